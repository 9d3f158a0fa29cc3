#!/usr/bin/env python3
"""Python client of the livereg registration server, standard library only.

HTTP (urllib) for sessions and single frames, and a small RFC 6455 WebSocket client (socket,
hashlib) for streams. Lengths are in the scene's units; results are in the cloud's frame.

    from livereg_client import Client
    c = Client("http://127.0.0.1:8080", token="...")
    sid = c.create_session_files("fixtures/liver_phantom/scene.toml")["id"]
    result = c.register(sid, [[x, y, z], ...])          # one frame, waits for its result
    result = c.register(sid, pts, binary_results=True)  # answered in the binary encoding
    with c.stream(sid) as ws:                           # WebSocket: newest frame wins
        ws.send_frame([[x, y, z], ...], seq=1)          # JSON; send_frame_binary for f32
        msg = ws.recv()                                 # {"type": "result", ...} or error
    with c.stream(sid, binary_results=True) as ws:      # results in the binary encoding,
        ...                                             # decoded by recv() to the same dict
    c.close_session(sid)

TLS: give an https:// URL (the WebSocket stream is then wss://). The server's certificate is
checked against the system's trust store, or against ca_file (PEM) when given:

    c = Client("https://or-3.example:8443", token="...", ca_file="/etc/livereg/ca.pem")

Command line (used by the tests):

    python3 livereg_client.py --url http://127.0.0.1:8080 --token-file tokens.txt \\
        [--ca-file CA.pem] roundtrip --scene SCENE --frames DIR --out results.jsonl --transport ws|ws-binary|http \\
        [--binary-results]
    python3 livereg_client.py decode-result FILE    # a binary result message -> JSON on stdout
"""

import argparse
import base64
import hashlib
import json
import os
import socket
import ssl
import struct
import sys
import time
import urllib.error
import urllib.parse
import urllib.request

__all__ = ["Client", "LiveregError", "WebSocket", "decode_binary_result", "encode_binary_frame"]

_WS_GUID = "258EAFA5-E914-47DA-95CA-C5AB0DC85B11"


# The header naming a session: the id a create asks for, and the key a scaled-out
# deployment's proxy routes every request of the session by (docs/server.md, "Scaling out").
SESSION_HEADER = "X-Livereg-Session"

# Answers that mean "this backend no longer has (or will not keep) the session": re-create
# it, with the same id, wherever the proxy now routes that id.
_MOVED_CODES = ("shutting_down", "not_found")


def new_session_id():
    """A session id chosen by the client: 128 random bits, 32 lowercase hex digits."""
    return os.urandom(16).hex()


class LiveregError(Exception):
    """An error answered by the server: HTTP status, code and message."""

    def __init__(self, status, code, message):
        super().__init__("%s %s: %s" % (status, code, message))
        self.status = status
        self.code = code
        self.message = message


def encode_binary_frame(points, seq=0, camera=None):
    """The compact binary frame (docs/server.md): little-endian header, then n x 3 float32."""
    flags = 1 if camera is not None else 0
    out = [b"LVRG", struct.pack("<BBHQI", 1, flags, 0, seq, len(points))]
    if camera is not None:
        pos, look, up = camera
        out.append(struct.pack("<9f", *pos, *look, *(up or (0.0, 0.0, 0.0))))
    flat = [c for p in points for c in p]
    out.append(struct.pack("<%df" % len(flat), *flat))
    return b"".join(out)


_RESULT_MAGIC = b"LVRR"
_RESULT_HEADER = 20


def decode_binary_result(data):
    """Decodes a binary result message (docs/server.md, "Binary result encoding") into the
    dict a JSON result gives: the metadata plus "surface" and "structures" ({name: points}),
    coordinates as floats (f32 precision, scene units, cloud frame). Raises ValueError saying
    what is wrong on a truncated, corrupted or inconsistent message."""
    data = bytes(data)
    if len(data) < _RESULT_HEADER:
        raise ValueError("binary result: %d bytes is shorter than the %d-byte header"
                         % (len(data), _RESULT_HEADER))
    if data[:4] != _RESULT_MAGIC:
        raise ValueError("binary result: does not start with the magic `LVRR`")
    if data[4] != 1:
        raise ValueError("binary result: version %d is not supported (this decoder reads "
                         "version 1)" % data[4])
    if data[5:8] != b"\0\0\0":
        raise ValueError("binary result: unknown flags or non-zero reserved bytes")
    m, v, s = struct.unpack_from("<III", data, 8)
    counts_end = _RESULT_HEADER + 4 * s
    if counts_end > len(data):
        raise ValueError("binary result: %d bytes cannot hold the counts of the %d structures "
                         "its header announces" % (len(data), s))
    counts = struct.unpack_from("<%dI" % s, data, _RESULT_HEADER)
    expected = counts_end + m + 12 * (v + sum(counts))
    if expected != len(data):
        raise ValueError("binary result: %d bytes, but its header announces %d bytes of "
                         "metadata, %d surface vertices and %d structures of %s points: "
                         "expected %d bytes" % (len(data), m, v, s, list(counts), expected))
    try:
        meta = json.loads(data[counts_end:counts_end + m].decode("utf-8"))
    except (UnicodeDecodeError, ValueError) as e:
        raise ValueError("binary result: malformed metadata JSON: %s" % e) from None
    if not isinstance(meta, dict) or meta.get("type") != "result":
        raise ValueError("binary result: the metadata is not a result object")
    names = meta.pop("structure_names", None)
    if not isinstance(names, list) or len(names) != s:
        raise ValueError("binary result: the metadata names %s structures, the header counts %d"
                         % (len(names) if isinstance(names, list) else "no", s))
    if len(set(map(str, names))) != s:
        raise ValueError("binary result: a structure name appears twice")

    def points(start, n):
        flat = struct.unpack_from("<%df" % (3 * n), data, start)
        return [list(flat[i:i + 3]) for i in range(0, 3 * n, 3)]

    at = counts_end + m
    meta["surface"] = points(at, v)
    at += 12 * v
    structures = {}
    for name, c in zip(names, counts):
        structures[str(name)] = points(at, c)
        at += 12 * c
    meta["structures"] = structures
    return meta


def _scene_files(scene_path):
    """The scene text and the files of its directory that it names (by quoted file name)."""
    with open(scene_path, "rb") as f:
        scene = f.read()
    text = scene.decode("utf-8")
    d = os.path.dirname(os.path.abspath(scene_path))
    files = {}
    for name in sorted(os.listdir(d)):
        p = os.path.join(d, name)
        if os.path.isfile(p) and os.path.abspath(p) != os.path.abspath(scene_path):
            if '"%s"' % name in text:
                with open(p, "rb") as f:
                    files[name] = f.read()
    return scene, files


def _multipart(parts):
    """A multipart/form-data body from (name, filename, bytes) parts: (content type, body)."""
    boundary = "livereg-" + base64.b16encode(os.urandom(12)).decode().lower()
    chunks = []
    for name, filename, data in parts:
        disp = 'form-data; name="%s"' % name
        if filename is not None:
            disp += '; filename="%s"' % filename
        chunks.append(
            ("--%s\r\nContent-Disposition: %s\r\nContent-Type: application/octet-stream\r\n\r\n"
             % (boundary, disp)).encode())
        chunks.append(data)
        chunks.append(b"\r\n")
    chunks.append(("--%s--\r\n" % boundary).encode())
    return "multipart/form-data; boundary=" + boundary, b"".join(chunks)


class Client:
    """HTTP client of one server with one bearer token."""

    def __init__(self, url, token=None, timeout=60.0, ca_file=None):
        self.url = url.rstrip("/")
        self.token = token
        self.timeout = timeout
        scheme = urllib.parse.urlparse(self.url).scheme
        if scheme not in ("http", "https"):
            raise ValueError("url %r: the scheme must be http or https" % url)
        # TLS: certificate and host name always checked (system roots, or ca_file's).
        self.tls = ssl.create_default_context(cafile=ca_file) if scheme == "https" else None

    def _request(self, method, path, body=None, content_type=None, raw=False, session=None):
        """Sends a request; returns the parsed JSON body (or None), or with raw=True the
        body's bytes. HTTP errors raise LiveregError with the server's code and message.
        session: the session id sent as X-Livereg-Session (the routing key of a scaled-out
        deployment, and the id a create asks for)."""
        headers = {}
        if session:
            headers[SESSION_HEADER] = session
        if self.token:
            headers["Authorization"] = "Bearer " + self.token
        if content_type:
            headers["Content-Type"] = content_type
        req = urllib.request.Request(self.url + path, data=body, method=method, headers=headers)
        try:
            with urllib.request.urlopen(req, timeout=self.timeout, context=self.tls) as r:
                data = r.read()
                if raw:
                    return data
                return json.loads(data) if data else None
        except urllib.error.HTTPError as e:
            raw = e.read()
            try:
                err = json.loads(raw)["error"]
                raise LiveregError(e.code, err["code"], err["message"]) from None
            except (ValueError, KeyError, TypeError):
                raise LiveregError(e.code, "http", raw.decode("utf-8", "replace")) from None

    # Sessions.
    def create_session_files(self, scene_path, budget_ms=None, rigid_only=False,
                             session_id=None):
        """Creates a session by uploading the scene file and the files it names (multipart);
        session_id: the id to give it (new_session_id(); needed behind a routing proxy)."""
        scene, files = _scene_files(scene_path)
        ext = "json" if scene_path.lower().endswith(".json") else "toml"
        parts = [("scene", "scene." + ext, scene)]
        parts += [("file", name, data) for name, data in files.items()]
        if budget_ms is not None:
            parts.append(("budget_ms", None, str(budget_ms).encode()))
        if rigid_only:
            parts.append(("rigid_only", None, b"true"))
        ctype, body = _multipart(parts)
        return self._request("POST", "/v1/sessions", body, ctype, session=session_id)

    def create_session_inline(self, scene, meshes=None, points=None, files=None, **options):
        """Creates a session from a scene (dict, or TOML text) and inline arrays:
        meshes = {"liver.obj": {"vertices": [[x,y,z],...], "triangles": [[i,j,k],...]}},
        points = {"targets.xyz": [[x,y,z],...]}, files = {"name": "text"}."""
        body = {"scene": scene, "meshes": meshes or {}, "points": points or {}, "files": files or {}}
        body.update(options)
        return self._request("POST", "/v1/sessions", json.dumps(body).encode(), "application/json")

    def get_session(self, sid):
        return self._request("GET", "/v1/sessions/" + sid, session=sid)

    def list_sessions(self):
        return self._request("GET", "/v1/sessions")["sessions"]

    def reset_session(self, sid):
        return self._request("POST", "/v1/sessions/%s/reset" % sid, session=sid)

    def close_session(self, sid):
        return self._request("DELETE", "/v1/sessions/" + sid, session=sid)

    # Frames.
    def register(self, sid, points, seq=0, source=None, camera=None, binary_results=False):
        """Registers one frame (JSON, full precision) and returns its result. With
        binary_results the server answers in the binary result encoding (f32 coordinates,
        about 5x smaller), decoded here into the same dict."""
        frame = {"seq": seq, "points": [list(map(float, p)) for p in points]}
        if source:
            frame["source"] = source
        if camera:
            frame["camera"] = camera
        return self._post_frame(sid, json.dumps(frame).encode(), "application/json",
                                binary_results)

    def register_binary(self, sid, points, seq=0, camera=None, binary_results=False):
        """Registers one frame in the binary encoding (float32); binary_results as in
        register()."""
        return self._post_frame(sid, encode_binary_frame(points, seq, camera),
                                "application/octet-stream", binary_results)

    def _post_frame(self, sid, body, content_type, binary_results):
        path = "/v1/sessions/%s/frames" % sid
        if not binary_results:
            return self._request("POST", path, body, content_type, session=sid)
        data = self._request("POST", path + "?results=binary", body, content_type, raw=True,
                             session=sid)
        result = decode_binary_result(data)
        result.pop("type", None)  # a JSON POST result has no message type
        return result

    def stream(self, sid, binary_results=False):
        """A WebSocket stream of the session (use as a context manager). With binary_results
        the server sends results in the binary result encoding (f32 coordinates, much smaller
        than JSON); recv() decodes them to the same dict as a JSON result."""
        path = "/v1/sessions/%s/stream" % sid
        if binary_results:
            path += "?results=binary"
        return WebSocket(self.url, path, self.token, self.timeout, binary_results, self.tls,
                         session=sid)

    def health(self):
        return self._request("GET", "/healthz")


class WebSocket:
    """A minimal RFC 6455 client (no extensions): text and binary messages, over ws:// for an
    http URL and wss:// for an https URL (tls: the ssl.SSLContext that checks the server).
    binary_results: binary messages are binary results, decoded by recv()."""

    def __init__(self, url, path, token, timeout=60.0, binary_results=False, tls=None,
                 session=None):
        self.binary_results = binary_results
        u = urllib.parse.urlparse(url)
        if u.scheme not in ("http", "https"):
            raise ValueError("url %r: the scheme must be http or https" % url)
        host, port = u.hostname, u.port or (443 if u.scheme == "https" else 80)
        sock = socket.create_connection((host, port), timeout=timeout)
        sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        if u.scheme == "https":
            tls = tls or ssl.create_default_context()
            try:
                sock = tls.wrap_socket(sock, server_hostname=host)
            except Exception:
                sock.close()
                raise
        self.sock = sock
        key = base64.b64encode(os.urandom(16)).decode()
        lines = ["GET %s HTTP/1.1" % path, "Host: %s:%d" % (host, port), "Upgrade: websocket",
                 "Connection: Upgrade", "Sec-WebSocket-Key: " + key, "Sec-WebSocket-Version: 13"]
        if token:
            lines.append("Authorization: Bearer " + token)
        if session:
            lines.append("%s: %s" % (SESSION_HEADER, session))
        self.sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        self._buf = b""
        head = self._read_until(b"\r\n\r\n").decode("latin-1")
        status = int(head.split(" ", 2)[1])
        if status != 101:
            body = self._buf
            self.sock.close()
            try:
                err = json.loads(body)["error"]
                raise LiveregError(status, err["code"], err["message"])
            except (ValueError, KeyError):
                raise LiveregError(status, "http", head.splitlines()[0])
        accept = base64.b64encode(hashlib.sha1((key + _WS_GUID).encode()).digest()).decode()
        if ("sec-websocket-accept: " + accept).lower() not in head.lower():
            raise ConnectionError("bad Sec-WebSocket-Accept")
        self.closed = False

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def _read_until(self, marker):
        while marker not in self._buf:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("connection closed during the handshake")
            self._buf += chunk
        i = self._buf.index(marker) + len(marker)
        head, self._buf = self._buf[:i], self._buf[i:]
        return head

    def _read(self, n):
        while len(self._buf) < n:
            chunk = self.sock.recv(max(65536, n - len(self._buf)))
            if not chunk:
                raise ConnectionError("connection closed")
            self._buf += chunk
        out, self._buf = self._buf[:n], self._buf[n:]
        return out

    def _send(self, opcode, payload):
        n = len(payload)
        if n < 126:
            header = struct.pack("!BB", 0x80 | opcode, 0x80 | n)
        elif n < 65536:
            header = struct.pack("!BBH", 0x80 | opcode, 0x80 | 126, n)
        else:
            header = struct.pack("!BBQ", 0x80 | opcode, 0x80 | 127, n)
        mask = os.urandom(4)
        if n:
            full = (mask * (n // 4 + 1))[:n]
            masked = (int.from_bytes(payload, "big") ^ int.from_bytes(full, "big")).to_bytes(n, "big")
        else:
            masked = b""
        self.sock.sendall(header + mask + masked)

    def send_text(self, text):
        self._send(0x1, text.encode("utf-8"))

    def send_binary(self, data):
        self._send(0x2, data)

    def send_frame(self, points, seq=0, source=None):
        """Sends a frame as JSON (full precision)."""
        frame = {"seq": seq, "points": [list(map(float, p)) for p in points]}
        if source:
            frame["source"] = source
        self.send_text(json.dumps(frame))

    def send_frame_binary(self, points, seq=0, camera=None):
        """Sends a frame in the binary encoding (float32)."""
        self.send_binary(encode_binary_frame(points, seq, camera))

    def recv(self):
        """The next message as a dict; {"type": "close", "code": n} when the server closes.
        Binary messages are decoded results when the stream asked for binary results (a
        corrupted one raises ValueError), else {"type": "binary", "data": bytes}."""
        data, first_op = b"", None
        while True:
            b1, b2 = self._read(2)
            op, fin, n = b1 & 0x0F, b1 & 0x80, b2 & 0x7F
            if n == 126:
                n = struct.unpack("!H", self._read(2))[0]
            elif n == 127:
                n = struct.unpack("!Q", self._read(8))[0]
            mask = self._read(4) if b2 & 0x80 else None
            payload = self._read(n)
            if mask:
                payload = bytes(c ^ mask[i % 4] for i, c in enumerate(payload))
            if op == 0x9:  # ping
                self._send(0xA, payload)
                continue
            if op == 0xA:
                continue
            if op == 0x8:
                code = struct.unpack("!H", payload[:2])[0] if len(payload) >= 2 else 1005
                if not self.closed:
                    try:
                        self._send(0x8, payload[:2])
                    except OSError:
                        pass
                self.closed = True
                return {"type": "close", "code": code}
            if op != 0:
                first_op = op
            data += payload
            if fin:
                if first_op == 0x1:
                    return json.loads(data.decode("utf-8"))
                if self.binary_results:
                    return decode_binary_result(data)
                return {"type": "binary", "data": data}

    def close(self):
        if not self.closed:
            try:
                self._send(0x8, struct.pack("!H", 1000))
                self.closed = True
                deadline = time.time() + 5
                while time.time() < deadline:
                    if self.recv().get("type") == "close":
                        break
            except (OSError, ConnectionError, ValueError):
                pass
        self.sock.close()


def _read_points(path):
    pts = []
    with open(path) as f:
        for line in f:
            line = line.strip()
            if not line or line.startswith("#"):
                continue
            pts.append([float(v) for v in line.replace(",", " ").split()[:3]])
    return pts


class MovingSession:
    """A session that follows its id across backends (a drained or lost server): it holds
    its scene, sends X-Livereg-Session on every request, and when a backend says the session
    is gone or moving (503 shutting_down, 404 not_found, a closed stream, a refused or broken
    connection) re-creates it with the same id wherever the proxy now routes that id, and
    sends the unanswered frame again. `moves` counts the re-creations; the registration
    restarts cold after each."""

    def __init__(self, client, scene_path, give_up_s=60.0):
        self.client, self.scene_path, self.give_up_s = client, scene_path, give_up_s
        self.id = new_session_id()
        self.moves = 0
        self.client.create_session_files(scene_path, session_id=self.id)

    def recreate(self):
        deadline = time.time() + self.give_up_s
        while True:
            try:
                self.client.create_session_files(self.scene_path, session_id=self.id)
                self.moves += 1
                return
            except LiveregError as e:
                if e.code == "session_exists":
                    return  # still open where the id routes: nothing moved
                if e.code not in _MOVED_CODES and e.status not in (502, 503, 504):
                    raise
            except (OSError, ConnectionError):
                pass
            if time.time() > deadline:
                raise ConnectionError("session %s: no backend took it within %.0f s"
                                      % (self.id, self.give_up_s))
            time.sleep(0.1)

    def stream(self, frames, binary=False, binary_results=False):
        """Registers every (name, points) of frames in lock step over a WebSocket; returns
        the results in order, each frame answered once."""
        results, ws, k = [], None, 0
        while k < len(frames):
            name, pts = frames[k]
            try:
                if ws is None:
                    ws = self.client.stream(self.id, binary_results=binary_results)
                if binary:
                    ws.send_frame_binary(pts, seq=k)
                else:
                    ws.send_frame(pts, seq=k, source=name)
                msg = ws.recv()
            except LiveregError as e:
                if e.code not in _MOVED_CODES and e.status not in (502, 503, 504):
                    raise
                msg = {"type": "moved"}
            except (OSError, ConnectionError):
                msg = {"type": "moved"}
            if msg.get("type") == "result":
                results.append(msg)
                k += 1
                continue
            if msg.get("type") == "error" and msg["error"]["code"] not in _MOVED_CODES:
                raise LiveregError(0, msg["error"]["code"], msg["error"]["message"])
            # Closed, moved or gone: the frame was not answered; follow the session.
            if ws is not None:
                try:
                    ws.sock.close()
                except OSError:
                    pass
                ws = None
            self.recreate()
        if ws is not None:
            ws.close()
        return results


def _roundtrip(client, args):
    if args.follow_moves:
        names = sorted(n for n in os.listdir(args.frames) if n.endswith((".xyz", ".txt", ".csv")))
        frames = [(n, _read_points(os.path.join(args.frames, n))) for n in names]
        ms = MovingSession(client, args.scene)
        results = ms.stream(frames, binary=args.transport == "ws-binary",
                            binary_results=args.binary_results)
        with open(args.out, "w") as f:
            for r in results:
                f.write(json.dumps(r) + "\n")
        print(json.dumps({"session": ms.id, "frames": len(results), "moves": ms.moves}))
        return
    session = client.create_session_files(args.scene)
    sid = session["id"]
    names = sorted(n for n in os.listdir(args.frames) if n.endswith((".xyz", ".txt", ".csv")))
    results = []
    if args.transport == "http":
        for k, name in enumerate(names):
            pts = _read_points(os.path.join(args.frames, name))
            results.append(client.register(sid, pts, seq=k, source=name,
                                           binary_results=args.binary_results))
    else:
        with client.stream(sid, binary_results=args.binary_results) as ws:
            for k, name in enumerate(names):
                pts = _read_points(os.path.join(args.frames, name))
                if args.transport == "ws-binary":
                    ws.send_frame_binary(pts, seq=k)
                else:
                    ws.send_frame(pts, seq=k, source=name)
                msg = ws.recv()
                if msg.get("type") != "result":
                    raise SystemExit("frame %d: %s" % (k, msg))
                results.append(msg)
    info = client.close_session(sid)
    with open(args.out, "w") as f:
        for r in results:
            f.write(json.dumps(r) + "\n")
    print(json.dumps({"session": sid, "frames": len(results),
                      "frames_registered": info["frames_registered"]}))


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--url", default="http://127.0.0.1:8080")
    p.add_argument("--token-file", help="first line: name:token or token (else $LIVEREG_TOKEN)")
    p.add_argument("--ca-file", help="PEM CA certificates that sign an https server's "
                                     "certificate (default: the system's trust store)")
    sub = p.add_subparsers(dest="cmd", required=True)
    r = sub.add_parser("roundtrip", help="create, send every frame of DIR, write results, close")
    r.add_argument("--scene", required=True)
    r.add_argument("--frames", required=True)
    r.add_argument("--out", required=True)
    r.add_argument("--transport", choices=["ws", "ws-binary", "http"], default="ws")
    r.add_argument("--binary-results", action="store_true",
                   help="results in the binary result encoding (f32 coordinates)")
    r.add_argument("--follow-moves", action="store_true",
                   help="choose the session id, send it on every request (X-Livereg-Session) "
                        "and re-create the session where its id routes when a backend drains "
                        "or goes away (WebSocket transports)")
    d = sub.add_parser("decode-result", help="decode a binary result message file to JSON")
    d.add_argument("file")
    sub.add_parser("health")
    args = p.parse_args(argv)
    token = os.environ.get("LIVEREG_TOKEN")
    if args.token_file:
        with open(args.token_file) as f:
            line = next(l.strip() for l in f if l.strip() and not l.startswith("#"))
        token = line.split(":", 1)[1] if ":" in line else line
    client = Client(args.url, token, ca_file=args.ca_file)
    try:
        if args.cmd == "roundtrip":
            _roundtrip(client, args)
        elif args.cmd == "decode-result":
            with open(args.file, "rb") as f:
                raw = f.read()
            try:
                print(json.dumps(decode_binary_result(raw)))
            except ValueError as e:
                print("livereg_client: %s" % e, file=sys.stderr)
                return 1
        else:
            print(json.dumps(client.health()))
    except LiveregError as e:
        print("livereg_client: %s" % e, file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())
