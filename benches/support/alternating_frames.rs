//! The warm-frame benchmarks' measurement: `Session::register` alternating between two nearby
//! frames, so that every measured frame has something to follow.

use std::hint::black_box;

use criterion::measurement::WallTime;
use criterion::{BenchmarkGroup, BenchmarkId};
use livereg::session::{Frame, Session};

/// Benchmarks `session` registering `a` and `b` in turn as `id` in `group`; every frame must
/// succeed.
pub fn bench_alternating_frames(
    group: &mut BenchmarkGroup<'_, WallTime>,
    id: BenchmarkId,
    session: &mut Session,
    a: &Frame,
    b: &Frame,
) {
    let mut flip = false;
    group.bench_function(id, |bench| {
        bench.iter(|| {
            flip = !flip;
            let f = if flip { a } else { b };
            let r = session.register(black_box(f));
            assert!(r.error.is_none(), "{:?}", r.error);
            r
        })
    });
}
