#!/usr/bin/env python3
"""Embree 4 (through the PyPI package `embreex`) on the meshes and rays that
`oxray bench --export DIR` writes, for a side-by-side comparison with oxray.

    python3 scripts/bench_embree.py DIR [--runs N] [--threads T] [--flags robust,none]
    python3 scripts/bench_embree.py --print-threads

Input (all little endian), for every NAME.mesh in DIR:
  NAME.mesh            u32 vertex count, u32 triangle count, f32x3 vertices, u32x3 triangles
  NAME.coherent.rays   f32[8] per ray: ox oy oz tmin dx dy dz tmax (tmax may be +inf)
  NAME.incoherent.rays same layout
  NAME.shadow.rays     same layout (optional; any hit only)
  NAME.coherent.oxray-hits (optional) f32 t per ray, +inf for a miss: cross-checked
Nothing is written into DIR.

What embreex's EmbreeScene.run(origins, directions, dists=None, query=..., output=None)
does (embreex 4.4.0.post1, embreex/rtcore_scene.pyx; confirmed at run time below):
  * a plain Cython `for i in range(nv)` loop that calls rtcIntersect1 / rtcOccluded1
    one ray at a time, in the calling thread, GIL held: ONE thread.  Later embreex
    sources add `threads=` (a oneTBB parallel_for); when run() accepts it this script
    passes threads=T.  The thread count is measured from per-thread CPU time in
    /proc/self/task either way, and printed.
  * ray.tnear is always 0.0: per-ray tmin is ignored.  The incoherent rays start on
    the surface with tmin = 1e-5 * radius, so this script moves their origins to
    o + tmin * d (and passes tfar = tmax - tmin, adding tmin back to reported t).
  * dists (one float32 per ray) is honoured as tfar; with query='DISTANCE' it is
    overwritten in place with the hit t (unchanged for a miss) and returned;
    'INTERSECT' returns int32 primID (-1 for a miss); 'OCCLUDED' returns int32
    0 (occluded) / -1.  The scene is committed (rtcCommitScene, the BVH build) lazily
    by the first run().
  * Build quality is not exposed (Embree's default, RTC_BUILD_QUALITY_MEDIUM); the
    only scene flag exposed is robust (RTC_SCENE_FLAG_ROBUST) via
    EmbreeScene(device, robust=...) (default True in embreex's source; this script
    passes it explicitly).  The BVH build runs on Embree's oneTBB pool, sized from
    the process's CPU affinity when the first device starts: this script pins the
    process to T CPUs while it creates the device, then restores the affinity, so the
    build uses T threads (measured and printed) that the OS may place on any CPU.
  * TriangleMesh copies vertices and indices element by element through untyped
    numpy indexing (slow Python-level work, not Embree): reported separately as
    "upload", not in "build".
Embree's per-call overhead from Python is measured and printed, never subtracted.
"""

import argparse
import glob
import inspect
import os
import subprocess
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))
VENV = os.path.join(HERE, ".venv-embree")
BOOT_ENV = "OXRAY_EMBREE_BOOTSTRAPPED"


def log(msg):
    print(msg, file=sys.stderr, flush=True)


def ensure_deps():
    """Imports numpy and embreex, installing them into scripts/.venv-embree (or, failing
    that, the user site) and re-executing this script when they are missing."""
    try:
        import numpy  # noqa: F401
        import embreex.mesh_construction  # noqa: F401
        import embreex.rtcore_scene  # noqa: F401
        return
    except ImportError:
        pass
    if os.environ.get(BOOT_ENV):
        sys.exit(f"error: numpy/embreex still not importable with {sys.executable}")
    env = dict(os.environ, **{BOOT_ENV: "1"})
    py = os.path.join(VENV, "bin", "python")
    try:
        if not os.path.exists(py):
            log(f"(installing embreex and numpy into {VENV})")
            subprocess.check_call([sys.executable, "-m", "venv", VENV], stdout=sys.stderr)
        subprocess.check_call(
            [py, "-m", "pip", "install", "--quiet", "--disable-pip-version-check", "embreex", "numpy"],
            stdout=sys.stderr)
    except (subprocess.CalledProcessError, OSError) as e:
        log(f"(venv failed: {e}; installing embreex and numpy with pip --user)")
        subprocess.check_call(
            [sys.executable, "-m", "pip", "install", "--quiet", "--user", "embreex", "numpy"],
            stdout=sys.stderr)
        py = sys.executable
    os.execve(py, [py, os.path.abspath(__file__)] + sys.argv[1:], env)


# ---------------------------------------------------------------------------------------
# Threads: per-thread CPU time from /proc/self/task.

def thread_cpu_seconds():
    """{tid: user+system CPU seconds} of this process's threads (Linux); {} elsewhere."""
    ticks = os.sysconf("SC_CLK_TCK")
    out = {}
    try:
        tids = os.listdir("/proc/self/task")
    except OSError:
        return out
    for tid in tids:
        try:
            with open(f"/proc/self/task/{tid}/stat") as f:
                s = f.read()
        except OSError:
            continue
        fields = s[s.rindex(")") + 2:].split()  # fields[0] is field 3 (state)
        out[tid] = (int(fields[11]) + int(fields[12])) / ticks  # utime, stime
    return out


class ThreadMeter:
    """Accumulates wall time, process CPU time and per-thread CPU time over measured calls."""

    def __init__(self):
        self.wall = 0.0
        self.cpu = 0.0
        self.per_thread = {}

    def measure(self, fn):
        th0 = thread_cpu_seconds()
        c0 = time.process_time()
        t0 = time.perf_counter()
        r = fn()
        t = time.perf_counter() - t0
        self.cpu += time.process_time() - c0
        self.wall += t
        th1 = thread_cpu_seconds()
        for tid, v in th1.items():
            self.per_thread[tid] = self.per_thread.get(tid, 0.0) + v - th0.get(tid, 0.0)
        return t, r

    def busy_threads(self):
        """Threads that ran for at least 10% of the wall time (and 20 ms): None without /proc."""
        if not self.per_thread:
            return None
        floor = max(0.02, 0.1 * self.wall)
        return sum(1 for v in self.per_thread.values() if v >= floor)

    def describe(self):
        busy = self.busy_threads()
        ratio = self.cpu / self.wall if self.wall > 0 else float("nan")
        b = "?" if busy is None else str(busy)
        return f"{b} busy thread(s), CPU/wall {ratio:.2f} over {self.wall:.2f} s"


def run_accepts_threads():
    from embreex import rtcore_scene
    try:
        return "threads" in inspect.signature(rtcore_scene.EmbreeScene.run).parameters
    except (TypeError, ValueError):
        return False


def pin_cpus(n):
    """Restricts this process to n CPUs, before Embree (oneTBB) sizes its thread pool; returns
    the previous CPU set."""
    old = os.sched_getaffinity(0)
    cpus = sorted(old)
    if n > len(cpus):
        log(f"warning: {n} threads asked for, only {len(cpus)} CPUs available")
        n = len(cpus)
    os.sched_setaffinity(0, cpus[:n])
    return old


def sphere_mesh(np, n=128):
    """A UV sphere of 2*n*n triangles (for the thread probe)."""
    th = np.linspace(0, np.pi, n + 1)
    ph = np.linspace(0, 2 * np.pi, n + 1)
    t, p = np.meshgrid(th, ph, indexing="ij")
    v = np.stack([np.sin(t) * np.cos(p), np.sin(t) * np.sin(p), np.cos(t)], -1).reshape(-1, 3)
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    a = (i * (n + 1) + j).ravel()
    b, c, d = a + 1, a + n + 1, a + n + 2
    tris = np.concatenate([np.stack([a, c, b], -1), np.stack([b, c, d], -1)])
    return v.astype(np.float32), tris.astype(np.int32)


def probe_threads():
    """Measures how many threads embreex's run() traces with (default arguments)."""
    import numpy as np
    from embreex import mesh_construction, rtcore, rtcore_scene
    v, t = sphere_mesh(np)
    scene = rtcore_scene.EmbreeScene(rtcore.EmbreeDevice())
    mesh_construction.TriangleMesh(scene, v, t)
    rng = np.random.default_rng(1)
    n = 1 << 20
    org = (rng.normal(size=(n, 3)) * 3).astype(np.float32)
    d = (rng.normal(size=(n, 3)) * 0.3 - org).astype(np.float32)
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    scene.run(org[:1], d[:1])  # commit
    m = ThreadMeter()
    while m.wall < 0.5:
        m.measure(lambda: scene.run(org, d, query="INTERSECT"))
    return m


# ---------------------------------------------------------------------------------------
# Benchmark.

def median(xs):
    xs = sorted(xs)
    n = len(xs)
    if n == 0:
        return float("nan")
    return xs[n // 2] if n % 2 else 0.5 * (xs[n // 2 - 1] + xs[n // 2])


def load_mesh(np, path):
    raw = np.fromfile(path, dtype=np.uint8)
    nv, nt = (int(x) for x in raw[:8].view("<u4"))
    need = 8 + 12 * nv + 12 * nt
    if raw.size != need:
        raise ValueError(f"{path}: {raw.size} bytes, expected {need} for {nv} vertices, {nt} triangles")
    v = raw[8:8 + 12 * nv].view("<f4").reshape(nv, 3).astype(np.float32)
    t = raw[8 + 12 * nv:].view("<u4").reshape(nt, 3)
    if nt and int(t.max()) >= nv:
        raise ValueError(f"{path}: vertex index out of range")
    return v, t.astype(np.int32)


class RaySet:
    """Rays as embreex takes them: origins moved to o + tmin*d (embreex's tnear is 0)."""

    def __init__(self, np, path):
        r = np.fromfile(path, dtype="<f4")
        if r.size % 8:
            raise ValueError(f"{path}: size is not a multiple of 32 bytes")
        r = r.reshape(-1, 8).astype(np.float32)
        self.n = r.shape[0]
        self.raw_org = np.ascontiguousarray(r[:, 0:3])
        self.dir = np.ascontiguousarray(r[:, 4:7])
        self.tmin = np.ascontiguousarray(r[:, 3])
        self.tmax = np.ascontiguousarray(r[:, 7])
        self.offset = bool(np.any(self.tmin != 0))
        if self.offset:
            self.org = (self.raw_org + self.tmin[:, None] * self.dir).astype(np.float32)
            self.tfar = (self.tmax - self.tmin).astype(np.float32)  # inf stays inf
        else:
            self.org = self.raw_org
            self.tfar = self.tmax.copy()


def timed_queries(scene, rays, query, runs, extra, meter):
    """Warm-up, then the median over `runs` of run() on all rays, in seconds."""
    args = []
    for _ in range(runs + 1):  # DISTANCE writes dists in place: a fresh copy per call
        args.append(rays.tfar.copy() if query == "DISTANCE" else rays.tfar)
    scene.run(rays.org, rays.dir, dists=args[0], query=query, **extra)
    times = []
    for k in range(runs):
        t, _ = meter.measure(lambda: scene.run(rays.org, rays.dir, dists=args[k + 1], query=query, **extra))
        times.append(t)
    return median(times)


def overhead(np, scene, v, extra, n=1 << 20, reps=7):
    """embreex + Embree cost per call and per ray for rays that miss the scene's bounds."""
    lo, hi = v.min(0), v.max(0)
    c, r = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2 + 1.0
    org = np.tile((c + np.array([4 * r, 0, 0])).astype(np.float32), (n, 1))
    d = np.tile(np.array([1, 0, 0], np.float32), (n, 1))
    tf = np.full(n, np.inf, np.float32)
    out = {}
    one = []
    for _ in range(201):
        t0 = time.perf_counter()
        scene.run(org[:1], d[:1], dists=tf[:1].copy(), query="INTERSECT", **extra)
        one.append(time.perf_counter() - t0)
    out["call_us"] = median(one) * 1e6
    for q in ("INTERSECT", "DISTANCE", "OCCLUDED"):
        ts = []
        for _ in range(reps):
            dist = tf.copy()
            t0 = time.perf_counter()
            scene.run(org, d, dists=dist, query=q, **extra)
            ts.append(time.perf_counter() - t0)
        out[q] = median(ts) / n * 1e9
    return out


def cross_check(np, scene, rays, hits_path, extra):
    """Compares Embree's closest hits with oxray's (f32 t per ray, +inf = miss)."""
    ox = np.fromfile(hits_path, dtype="<f4")
    if ox.size != rays.n:
        return f"{os.path.basename(hits_path)}: {ox.size} values for {rays.n} rays, skipped"
    res = scene.run(rays.org, rays.dir, dists=rays.tfar.copy(), query="DISTANCE", output=True, **extra)
    hit_e = res["primID"] >= 0
    t_e = np.where(hit_e, res["tfar"].astype(np.float64) + rays.tmin, np.inf)
    hit_o = np.isfinite(ox)
    t_o = ox.astype(np.float64)
    same_hit = hit_e == hit_o
    both = hit_e & hit_o
    with np.errstate(invalid="ignore"):
        t_ok = np.abs(t_e - t_o) <= 1e-4 * np.maximum(np.abs(t_e), np.abs(t_o))
    agree = same_hit & (~both | t_ok)
    nb = int(both.sum())
    return (f"{os.path.basename(hits_path)}: hit/miss agree {100 * same_hit.mean():.3f}% "
            f"({int((~same_hit).sum())} differ: {int((hit_e & ~hit_o).sum())} Embree-only hits, "
            f"{int((~hit_e & hit_o).sum())} oxray-only hits); "
            f"t within 1e-4 rel on {100 * (t_ok & both).sum() / max(nb, 1):.3f}% of {nb} common hits; "
            f"hit/miss and t agree on {100 * agree.mean():.3f}% of rays")


def bench(args, nthreads, probe):
    import numpy as np
    import embreex
    from embreex import mesh_construction, rtcore, rtcore_scene

    extra = {"threads": nthreads} if run_accepts_threads() else {}
    # In the order oxray wrote them (its table's order).
    meshes = sorted(glob.glob(os.path.join(args.dir, "*.mesh")), key=lambda p: (os.path.getmtime(p), p))
    if not meshes:
        sys.exit(f"error: no *.mesh in {args.dir} (write them with `oxray bench --export {args.dir}`)")
    flags = [f.strip() for f in args.flags.split(",") if f.strip()]
    for f in flags:
        if f not in ("robust", "none"):
            sys.exit(f"error: --flags takes robust and/or none, got {f!r}")

    # oneTBB's pool is sized from the CPU affinity when the first Embree device starts: pin the
    # process to nthreads CPUs for that, then give it its CPUs back so that the OS may run those
    # threads anywhere (on a shared machine a pinned CPU may be busy).
    old = pin_cpus(nthreads)
    device = rtcore.EmbreeDevice()
    os.sched_setaffinity(0, old)
    ver = getattr(embreex, "__version__", "?")
    print(f"{str(device).strip()} via embreex {ver} (numpy {np.__version__}, Python {sys.version.split()[0]})")
    print(f"threads: {nthreads} (oneTBB pool sized to {nthreads} by pinning the process while the "
          f"Embree device starts; {len(old)} CPUs available after that), "
          f"median of {args.runs} runs after a warm-up, "
          f"run() {'threads=' + str(nthreads) if extra else 'has no threads argument (serial loop)'}")
    if probe:
        print(f"thread probe (unpinned, default arguments, 2^20 rays on a sphere): {probe}")
    print("| mesh | tris | scene flags | build ms (rtcCommitScene) | upload ms (embreex TriangleMesh) "
          "| coherent closest | coherent any | incoherent closest | incoherent any | shadow any | hit rate coherent / incoherent |")
    print("|---|---:|---|---:|---:|---:|---:|---:|---:|---:|---|")

    notes = []
    build_meter = ThreadMeter()
    trace_meter = {q: ThreadMeter() for q in ("closest", "OCCLUDED")}
    closest_q = None
    for path in meshes:
        name = os.path.basename(path)[:-len(".mesh")]
        v, t = load_mesh(np, path)
        sets = {}
        for kind in ("coherent", "incoherent", "shadow"):
            p = os.path.join(args.dir, f"{name}.{kind}.rays")
            if os.path.exists(p):
                sets[kind] = RaySet(np, p)
        for flag in flags:
            robust = flag == "robust"
            upload, build = [], []
            one_o, one_d = v[:1].copy(), np.array([[0, 0, 1]], np.float32)
            scene = None
            for _ in range(args.runs):
                del scene  # release the previous BVH first
                t0 = time.perf_counter()
                scene = rtcore_scene.EmbreeScene(device, robust=robust)
                mesh_construction.TriangleMesh(scene, v, t)
                upload.append(time.perf_counter() - t0)
                # The first run() commits the scene: the BVH build (+ one ray, ~1 us).
                tb, _ = build_meter.measure(lambda: scene.run(one_o, one_d, query="OCCLUDED", **extra))
                build.append(tb)
            if closest_q is None:
                oh = overhead(np, scene, v, extra)
                closest_q = "INTERSECT" if oh["INTERSECT"] <= oh["DISTANCE"] else "DISTANCE"
                close = abs(oh["INTERSECT"] - oh["DISTANCE"]) <= 0.05 * max(oh["INTERSECT"], oh["DISTANCE"])
                notes.append(
                    f"embreex per-call overhead (not subtracted; {name}, {flag}): {oh['call_us']:.1f} us per run() call "
                    f"(1 ray); per ray, on rays missing the scene's bounds (Cython loop + Embree entry + root box test): "
                    f"INTERSECT {oh['INTERSECT']:.1f} ns, DISTANCE {oh['DISTANCE']:.1f} ns, OCCLUDED {oh['OCCLUDED']:.1f} ns "
                    f"-> closest hit timed with query='{closest_q}'"
                    + (" (INTERSECT and DISTANCE within 5%: the same loop, noise)" if close else ""))
            mr = {}
            hit = {}
            for kind, rays in sets.items():
                s = timed_queries(scene, rays, "OCCLUDED", args.runs, extra, trace_meter["OCCLUDED"])
                mr[kind, "any"] = rays.n / s / 1e6
                if kind == "shadow":
                    continue  # shadow rays: any hit only
                s = timed_queries(scene, rays, closest_q, args.runs, extra, trace_meter["closest"])
                mr[kind, "closest"] = rays.n / s / 1e6
                ids = scene.run(rays.org, rays.dir, dists=rays.tfar, query="INTERSECT", **extra)
                hit[kind] = float(np.mean(ids >= 0))
                hp = os.path.join(args.dir, f"{name}.{kind}.oxray-hits")
                if os.path.exists(hp):
                    notes.append(f"{name} ({flag}): " + cross_check(np, scene, rays, hp, extra))
                elif kind == "coherent" and flag == flags[0]:
                    notes.append(f"{name}: no {os.path.basename(hp)}, results not cross-checked")
                if flag == flags[0]:
                    if rays.offset:
                        # What tnear = 0 would do: hits closer than tmin (self-intersections).
                        dist = scene.run(rays.raw_org, rays.dir, dists=rays.tmax.copy(), query="DISTANCE", **extra)
                        selfhits = float(np.mean(dist < rays.tmin))
                        notes.append(
                            f"{name}.{kind}: tmin > 0 (max {float(rays.tmin.max()):.3g}) but embreex sets tnear = 0: "
                            f"origins offset to o + tmin*d for Embree; without the offset "
                            f"{100 * selfhits:.2f}% of these rays hit at t < tmin (self-hits)")

            def f(kind, q):
                return f"{mr[kind, q]:.2f}" if (kind, q) in mr else "-"
            hr = " / ".join(f"{100 * hit[k]:.1f}%" if k in hit else "-" for k in ("coherent", "incoherent"))
            print(f"| {name} | {len(t)} | {flag} | {median(build) * 1e3:.1f} "
                  f"| {median(upload) * 1e3:.1f} | {f('coherent', 'closest')} | {f('coherent', 'any')} "
                  f"| {f('incoherent', 'closest')} | {f('incoherent', 'any')} | {f('shadow', 'any')} | {hr} |", flush=True)
            del scene
            scene = None

    print()
    print(f"Embree threads measured (per-thread CPU time, /proc/self/task): "
          f"run() closest ({closest_q}): {trace_meter['closest'].describe()}; "
          f"run() OCCLUDED: {trace_meter['OCCLUDED'].describe()}; "
          f"BVH build (rtcCommitScene, oneTBB): {build_meter.describe()}")
    for q, m in trace_meter.items():
        busy = m.busy_threads()
        if busy is not None and busy != nthreads:
            print(f"WARNING: run() ({closest_q if q == 'closest' else q}) traced with {busy} thread(s), "
                  f"not {nthreads}: the comparison is not at equal thread counts")
    for n in notes:
        print(n)
    print("Notes: Mrays/s = rays / median wall time of one run() over the whole set, including embreex's "
          "per-call and per-ray overhead above. Build quality is Embree's default (MEDIUM; embreex exposes no "
          "other); scene flags 'robust' = RTC_SCENE_FLAG_ROBUST (embreex's default), 'none' = RTC_SCENE_FLAG_NONE (Embree's default). "
          "Build = rtcCommitScene only (timed through the first run() of one ray); upload = embreex's "
          "element-by-element copy into Embree's buffers (Python-level, not Embree).")


def main():
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dir", nargs="?", help="directory written by `oxray bench --export DIR`")
    ap.add_argument("--runs", type=int, default=5, help="repetitions; the median is reported (default 5)")
    ap.add_argument("--threads", type=int, default=None,
                    help="threads for Embree (default: the number embreex's run() traces with, measured)")
    ap.add_argument("--flags", default="robust,none",
                    help="scene flags to benchmark, comma-separated: robust, none (default: both)")
    ap.add_argument("--print-threads", action="store_true",
                    help="print how many threads embreex's run() uses (measured) and exit")
    args = ap.parse_args()
    ensure_deps()

    if args.print_threads:
        m = probe_threads()
        busy = m.busy_threads()
        if busy is None:  # no /proc: fall back on CPU time / wall time
            busy = max(1, round(m.cpu / m.wall))
        log(f"embreex run(): {m.describe()}")
        print(busy)
        return
    if args.dir is None:
        ap.error("DIR is required (or --print-threads)")
    if args.runs < 1:
        ap.error("--runs must be at least 1")
    if args.threads is None:
        out = subprocess.run([sys.executable, os.path.abspath(__file__), "--print-threads"],
                             check=True, capture_output=True, text=True)
        nthreads = int(out.stdout.strip().splitlines()[-1])
        probe = out.stderr.strip().splitlines()[-1].replace("embreex run(): ", "run() used ")
    else:
        nthreads, probe = args.threads, None
    if nthreads < 1:
        ap.error("--threads must be at least 1")
    bench(args, nthreads, probe)


if __name__ == "__main__":
    main()
