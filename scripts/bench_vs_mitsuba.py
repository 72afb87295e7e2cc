#!/usr/bin/env python3
"""Time to equal error: oxray's path tracer against Mitsuba 3 (llvm_ad_rgb) on the same scenes.

Scenes, each built identically in both renderers:
  cornell  oxray's built-in Cornell box (crates/oxray-scene/src/cornell.rs): its quads, camera,
           Lambertian albedos and one-sided area light, rebuilt in Mitsuba from the same numbers.
  gltf     a glTF scene (default ../shared/data/gltf/balloon) flattened to triangles, one
           Lambertian material per glTF material (albedo: base colour factor times the mean of
           its base colour texture), flat-shaded, on a grey ground (albedo 0.5) under a
           constant white sky (radiance 1). oxray
           renders it as an OBJ+MTL file and Mitsuba as one PLY per material: the same
           triangles. Skipped when the glTF file is absent.
Both renderers: box pixel filter, paths of at most --max-depth vertices (oxray's --max-depth and
Mitsuba's max_depth count alike), each renderer's own Russian roulette at its default (oxray's
from the 3rd vertex with three times the throughput as the probability to go on; Mitsuba's
rr_depth=5, the throughput itself; --mitsuba-rr-depth changes it), two-sided surfaces, linear
RGB (no tone mapping), the same thread count.

Steps per scene:
  1. The reference and the check that the two scenes agree: oxray (sobol) and Mitsuba, each
     at --ref-spp samples per pixel, compared per channel (mean difference over its standard
     error) and in 16x16-pixel blocks: a difference beyond the noise means the scenes differ.
     The reference is their mean; the variance it keeps (a quarter of their mean squared
     difference) is subtracted from every MSE below.
  2. For each spp of --ladder (Mitsuba also at 4x its largest, to span oxray's errors),
     --repeats times, alternating oxray (each sampler of --samplers: sobol, its default, and
     independent) and Mitsuba (each sampler of --mitsuba-samplers: independent, its default,
     and ldsampler, scrambled (0,2)-sequences, the counterpart of oxray's Sobol) so that
     machine load falls on both alike: the render's wall time and its RMSE against the
     reference, over all pixels and over the pixels below 1 in every channel of the reference
     (the light and its edges excluded). oxray's time is that of its passes as the CLI
     reports them (no process start, scene loading or image writing, and not the render's
     setup: the BVH build and the light tables, reported apart, as Mitsuba builds its BVH when
     the scene loads). Mitsuba's is the wall time of mi.render()
     until the image is evaluated, after a warm-up render of the same spp with another seed (so
     no JIT compilation is counted).
  3. Time to equal RMSE: for target RMSEs (those oxray's sobol sampler reaches at the ladder's
     spp), each renderer's time interpolated along its time-RMSE curve in log-log, and the ratio
     oxray / Mitsuba. Also the time per spp (the slope of time over spp).
A markdown report goes to standard output and to --out/report.md.

Usage (one go; installs Mitsuba with scripts/setup-mitsuba.sh and builds oxray if needed):
  python3 scripts/bench_vs_mitsuba.py [--threads 2] [--size 256x256] [--scenes cornell,gltf]
  [--oxray PATH]   # another oxray binary (e.g. an earlier commit's, for a before/after run)
"""

from __future__ import annotations

import argparse
import base64
import json
import math
import os
import re
import shutil
import statistics
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def ensure_mitsuba_python() -> None:
    """Re-runs this script under the venv of scripts/setup-mitsuba.sh (with DRJIT_LIBLLVM_PATH)."""
    if os.environ.get("OXRAY_BENCH_MITSUBA_CHILD") == "1":
        return
    out = subprocess.run(
        [str(ROOT / "scripts" / "setup-mitsuba.sh")], check=True, capture_output=True, text=True
    ).stdout.split("\n")
    py, llvm = out[0].strip(), out[1].strip().split("=", 1)[1]
    env = dict(os.environ, OXRAY_BENCH_MITSUBA_CHILD="1")
    if llvm:
        env["DRJIT_LIBLLVM_PATH"] = llvm
    os.execve(py, [py, __file__, *sys.argv[1:]], env)


# Only as a script: importing the module (for its scene helpers) must not start a benchmark.
if __name__ == "__main__":
    ensure_mitsuba_python()

import drjit as dr  # noqa: E402
import mitsuba as mi  # noqa: E402
import numpy as np  # noqa: E402

VARIANT = "llvm_ad_rgb" if os.environ.get("DRJIT_LIBLLVM_PATH") else "scalar_rgb"
mi.set_variant(VARIANT)

# ---------------------------------------------------------------------------------------------
# Scenes


def cornell_geometry() -> tuple[dict, dict]:
    """oxray's cornell_box() (crates/oxray-scene/src/cornell.rs), quad for quad: returns
    ({material: (positions N x 3, triangles M x 3)}, camera)."""
    scale, light_y = 555.0, 548.3
    quads: dict[str, list] = {"white": [], "red": [], "green": [], "light": []}
    quads["white"] += [
        [[552.8, 0, 0], [0, 0, 0], [0, 0, 559.2], [549.6, 0, 559.2]],
        [[556, 548.8, 0], [556, 548.8, 559.2], [0, 548.8, 559.2], [0, 548.8, 0]],
        [[549.6, 0, 559.2], [0, 0, 559.2], [0, 548.8, 559.2], [556, 548.8, 559.2]],
    ]
    quads["red"].append([[552.8, 0, 0], [549.6, 0, 559.2], [556, 548.8, 559.2], [556, 548.8, 0]])
    quads["green"].append([[0, 0, 559.2], [0, 0, 0], [0, 548.8, 0], [0, 548.8, 559.2]])
    quads["light"].append(
        [[343, light_y, 227], [343, light_y, 332], [213, light_y, 332], [213, light_y, 227]]
    )

    def block(top, h):
        a, b, c, d = top
        quads["white"].append([[p[0], h, p[1]] for p in (a, b, c, d)])
        for p, q in [(d, c), (a, d), (b, a), (c, b)]:
            quads["white"].append([[p[0], 0, p[1]], [p[0], h, p[1]], [q[0], h, q[1]], [q[0], 0, q[1]]])

    block([[130, 65], [82, 225], [240, 272], [290, 114]], 165)
    block([[423, 247], [265, 296], [314, 456], [472, 406]], 330)
    meshes = {}
    for name, qs in quads.items():
        pos = np.array(qs, dtype=np.float64).reshape(-1, 3) / scale
        tris = np.array([[4 * k, 4 * k + 1, 4 * k + 2, 4 * k, 4 * k + 2, 4 * k + 3] for k in range(len(qs))])
        meshes[name] = (pos.astype(np.float32), tris.reshape(-1, 3).astype(np.uint32))
    eye = np.array([278.0, 273.0, -800.0]) / scale
    camera = {"origin": eye, "target": eye + [0, 0, 1], "up": [0, 1, 0],
              "fov": math.degrees(2 * math.atan(12.5 / 35.0))}
    return meshes, camera


CORNELL_ALBEDO = {"white": [0.73] * 3, "red": [0.65, 0.05, 0.05], "green": [0.12, 0.45, 0.15],
                  "light": [0.78] * 3}
CORNELL_RADIANCE = [17.0, 12.0, 4.0]


def _accessor(g: dict, buffers: list[bytes], i: int) -> np.ndarray:
    a = g["accessors"][i]
    if "sparse" in a:
        raise ValueError("sparse accessors are not supported")
    view = g["bufferViews"][a["bufferView"]]
    dtype = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32,
             5126: np.float32}[a["componentType"]]
    n = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT4": 16}[a["type"]]
    item = np.dtype(dtype).itemsize * n
    stride = view.get("byteStride", item)
    start = view.get("byteOffset", 0) + a.get("byteOffset", 0)
    raw = np.frombuffer(buffers[view["buffer"]], dtype=np.uint8,
                        count=stride * (a["count"] - 1) + item, offset=start)
    rows = np.lib.stride_tricks.as_strided(raw, (a["count"], item), (stride, 1))
    return np.ascontiguousarray(rows).view(dtype).reshape(a["count"], n)


def _node_matrix(node: dict) -> np.ndarray:
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
    t = np.eye(4)
    t[:3, 3] = node.get("translation", [0, 0, 0])
    x, y, z, w = node.get("rotation", [0, 0, 0, 1])
    r = np.eye(4)
    r[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    s = np.diag([*node.get("scale", [1, 1, 1]), 1.0])
    return t @ r @ s


def _texture_mean(g: dict, folder: Path, tex: dict | None) -> np.ndarray:
    """The mean linear colour of a base colour texture (ones when there is none or it cannot
    be read)."""
    if tex is None:
        return np.ones(3)
    try:
        from PIL import Image

        uri = g["images"][g["textures"][tex["index"]]["source"]]["uri"]
        with Image.open(folder / uri) as im:
            px = np.asarray(im.convert("RGB").resize((64, 64)), dtype=np.float64) / 255.0
        lin = np.where(px <= 0.04045, px / 12.92, ((px + 0.055) / 1.055) ** 2.4)
        return lin.reshape(-1, 3).mean(axis=0)
    except Exception as e:  # a missing texture or Pillow: the factor alone
        print(f"note: texture not read ({e}); using the base colour factor", file=sys.stderr)
        return np.ones(3)


def gltf_geometry(path: Path) -> tuple[dict, dict, dict]:
    """Flattens a glTF file's default scene to triangles per material: returns
    ({material: (positions, triangles)}, {material: albedo}, camera)."""
    g = json.loads(path.read_text())
    buffers = []
    for b in g["buffers"]:
        uri = b["uri"]
        if uri.startswith("data:"):
            buffers.append(base64.b64decode(uri.split(",", 1)[1]))
        else:
            buffers.append((path.parent / uri).read_bytes())
    parts: dict[int, list] = {}

    def visit(i: int, parent: np.ndarray) -> None:
        node = g["nodes"][i]
        m = parent @ _node_matrix(node)
        if "mesh" in node:
            for prim in g["meshes"][node["mesh"]]["primitives"]:
                if prim.get("mode", 4) != 4:
                    continue
                pos = _accessor(g, buffers, prim["attributes"]["POSITION"]).astype(np.float64)
                pos = pos @ m[:3, :3].T + m[:3, 3]
                if "indices" in prim:
                    idx = _accessor(g, buffers, prim["indices"]).reshape(-1, 3).astype(np.uint32)
                else:
                    idx = np.arange(len(pos), dtype=np.uint32).reshape(-1, 3)
                if np.linalg.det(m[:3, :3]) < 0:
                    idx = idx[:, ::-1]
                parts.setdefault(prim.get("material", -1), []).append((pos, idx))
        for c in node.get("children", []):
            visit(c, m)

    for root in g["scenes"][g.get("scene", 0)]["nodes"]:
        visit(root, np.eye(4))
    meshes, albedo = {}, {}
    for mat, chunks in sorted(parts.items()):
        offs = np.cumsum([0] + [len(p) for p, _ in chunks])
        pos = np.concatenate([p for p, _ in chunks]).astype(np.float32)
        tris = np.concatenate([t + o for (_, t), o in zip(chunks, offs)]).astype(np.uint32)
        name = f"m{mat + 1}"
        meshes[name] = (pos, tris)
        if mat < 0:
            albedo[name] = [0.8] * 3
        else:
            pbr = g["materials"][mat].get("pbrMetallicRoughness", {})
            factor = np.array(pbr.get("baseColorFactor", [1, 1, 1, 1])[:3])
            c = factor * _texture_mean(g, path.parent, pbr.get("baseColorTexture"))
            albedo[name] = [round(float(v), 4) for v in np.clip(c, 0.0, 0.95)]
    allpos = np.concatenate([p for p, _ in meshes.values()])
    lo, hi = allpos.min(axis=0), allpos.max(axis=0)
    centre, radius = (lo + hi) / 2, float(np.linalg.norm(hi - lo)) / 2
    # A grey ground under the model, 40 radii wide, facing up.
    x0, x1, z0, z1 = centre[0] - 20 * radius, centre[0] + 20 * radius, centre[2] - 20 * radius, centre[2] + 20 * radius
    ground = np.array([[x0, lo[1], z0], [x0, lo[1], z1], [x1, lo[1], z1], [x1, lo[1], z0]], dtype=np.float32)
    meshes["ground"] = (ground, np.array([[0, 1, 2], [0, 2, 3]], dtype=np.uint32))
    albedo["ground"] = [0.5, 0.5, 0.5]
    fov = 40.0
    direction = np.array([0.55, 0.3, 1.0]) / np.linalg.norm([0.55, 0.3, 1.0])
    eye = centre + direction * radius / math.sin(math.radians(fov / 2)) * 1.05
    camera = {"origin": eye, "target": centre, "up": [0, 1, 0], "fov": fov}
    return meshes, albedo, camera


def write_ply(path: Path, pos: np.ndarray, tris: np.ndarray) -> None:
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pos)}\n"
            "property float x\nproperty float y\nproperty float z\n"
            f"element face {len(tris)}\nproperty list uchar uint vertex_indices\nend_header\n")
    faces = np.zeros(len(tris), dtype=[("n", "u1"), ("i", "<u4", 3)])
    faces["n"], faces["i"] = 3, tris
    with open(path, "wb") as f:
        f.write(head.encode())
        f.write(pos.astype("<f4").tobytes())
        f.write(faces.tobytes())


def write_obj(path: Path, meshes: dict, albedo: dict) -> None:
    """One OBJ+MTL with every material's triangles; Lambertian (illum 1) materials."""
    mtl = path.with_suffix(".mtl")
    mtl.write_text("".join(f"newmtl {n}\nKd {a[0]} {a[1]} {a[2]}\nillum 1\n\n" for n, a in albedo.items()))
    lines, base = [f"mtllib {mtl.name}\n"], 1
    for name, (pos, tris) in meshes.items():
        lines += [f"v {x:.9g} {y:.9g} {z:.9g}\n" for x, y, z in pos]
        lines.append(f"usemtl {name}\n")
        lines += [f"f {a + base} {b + base} {c + base}\n" for a, b, c in tris]
        base += len(pos)
    path.write_text("".join(lines))


def mitsuba_scene(meshes: dict, albedo: dict, camera: dict, size: tuple[int, int], max_depth: int,
                  folder: Path, emitter: dict | None = None, env: float | None = None,
                  sampler: str = "independent", rr_depth: int = 5):
    """The Mitsuba scene: one PLY per material (flat-shaded, two-sided diffuse), a pinhole
    camera with a box filter, the path integrator."""
    d = {"type": "scene",
         "integrator": {"type": "path", "max_depth": max_depth, "rr_depth": rr_depth},
         "sensor": {"type": "perspective", "fov": camera["fov"], "fov_axis": "y",
                    "near_clip": 1e-3, "far_clip": 1e4,
                    "to_world": mi.ScalarTransform4f().look_at(
                        origin=[float(v) for v in camera["origin"]],
                        target=[float(v) for v in camera["target"]], up=camera["up"]),
                    "sampler": {"type": sampler, "sample_count": 4},
                    "film": {"type": "hdrfilm", "width": size[0], "height": size[1],
                             "rfilter": {"type": "box"}, "pixel_format": "rgb"}}}
    for name, (pos, tris) in meshes.items():
        ply = folder / f"{name}.ply"
        write_ply(ply, pos, tris)
        shape = {"type": "ply", "filename": str(ply), "face_normals": True,
                 "bsdf": {"type": "twosided", "bsdf": {"type": "diffuse", "reflectance":
                                                       {"type": "rgb", "value": albedo[name]}}}}
        if emitter and name in emitter:
            shape["emitter"] = {"type": "area", "radiance": {"type": "rgb", "value": emitter[name]}}
        d[name] = shape
    if env is not None:
        d["env"] = {"type": "constant", "radiance": {"type": "rgb", "value": [env] * 3}}
    return mi.load_dict(d)


# ---------------------------------------------------------------------------------------------
# Rendering


def read_exr(path: Path) -> np.ndarray:
    return np.array(mi.Bitmap(str(path)).convert(mi.Bitmap.PixelFormat.RGB,
                                                 mi.Struct.Type.Float32, srgb_gamma=False))


class Oxray:
    def __init__(self, exe: Path, scene_args: list[str], size: str, max_depth: int,
                 threads: int, tmp: Path):
        self.exe, self.scene_args, self.size = exe, scene_args, size
        self.max_depth, self.threads, self.tmp = max_depth, threads, tmp

    def render(self, spp: int, seed: int, sampler: str) -> tuple[np.ndarray, float]:
        out = self.tmp / "oxray.exr"
        cmd = [str(self.exe), "render", *self.scene_args, "-o", str(out), "--size", self.size,
               "--spp", str(spp), "--seed", str(seed), "--sampler", sampler, "--filter", "box",
               "--max-depth", str(self.max_depth), "-t", str(self.threads), "--quiet"]
        text = subprocess.run(cmd, check=True, capture_output=True, text=True).stdout
        # Binaries before the setup was reported apart print no setup: their rate and seconds
        # include it.
        m = re.search(r"rendered in ([\d.]+) s \(([\d.]+) M samples/s, [\d.]+ Mrays/s"
                      r"(?: after ([\d.]+) s of setup)?\)", text)
        if not m:
            raise RuntimeError(f"unexpected oxray output: {text}")
        w, h = (int(v) for v in self.size.split("x"))
        secs, rate, setup = float(m.group(1)), float(m.group(2)), float(m.group(3) or 0.0)
        # The passes' time (the setup, BVH build and light tables, excluded as Mitsuba's
        # BVH build at load is). The CLI prints the seconds with one decimal and the rate (of
        # the passes) with two: take whichever is the more precise.
        passes = max(secs - setup, 1e-9)
        if rate > 0 and 0.005 / rate < 0.05 / passes:
            return read_exr(out), w * h * spp / (rate * 1e6)
        return read_exr(out), passes


class Mitsuba:
    def __init__(self, scene, threads: int):
        self.scene = scene
        dr.set_thread_count(threads)
        self.warm: set[int] = set()

    def _render(self, spp: int, seed: int) -> np.ndarray:
        img = mi.render(self.scene, spp=spp, seed=seed)
        dr.eval(img)
        dr.sync_thread()
        return img

    def render(self, spp: int, seed: int) -> tuple[np.ndarray, float]:
        if spp not in self.warm:
            self._render(spp, seed + 7919)  # JIT compilation, not timed
            self.warm.add(spp)
        t0 = time.perf_counter()
        img = self._render(spp, seed)
        t = time.perf_counter() - t0
        return np.array(img, dtype=np.float32)[..., :3], t

    def converged(self, spp: int, seed: int, chunk: int = 256) -> np.ndarray:
        acc, n = 0.0, 0
        while n < spp:
            k = min(chunk, spp - n)
            acc = acc + self.render(k, seed + n)[0] * k
            n += k
        return acc / spp


# ---------------------------------------------------------------------------------------------
# Error and report


def rmse(img: np.ndarray, ref: np.ndarray, mask: np.ndarray | None = None) -> float:
    d = (img.astype(np.float64) - ref) ** 2
    if mask is not None:
        d = d[mask]
    return float(np.sqrt(d.mean()))


def loglog_time_at(points: list[tuple[float, float]], target: float) -> float | None:
    """Time at RMSE `target` on a curve of (time, rmse) points: interpolated in log-log between
    the two points around it, or extrapolated from the end segment up to 2x beyond the curve;
    None further out."""
    pts = sorted(points, key=lambda p: -p[1])  # decreasing error
    if len(pts) < 2 or not pts[-1][1] / 2 <= target <= pts[0][1] * 2:
        return None
    k = next((i for i in range(len(pts) - 1) if pts[i + 1][1] <= target), len(pts) - 2)
    (t0, e0), (t1, e1) = pts[k], pts[k + 1]
    if not (e0 > e1 > 0 and t0 > 0 and t1 > 0):
        return None
    s = (math.log(t1) - math.log(t0)) / (math.log(e1) - math.log(e0))
    return math.exp(math.log(t0) + s * (math.log(target) - math.log(e0)))


def fit_time_per_spp(rows: list[tuple[int, float]]) -> tuple[float, float]:
    """Least-squares line of time over spp: the cost per spp (without fixed costs) and the
    fixed cost per render (the intercept)."""
    x = np.array([r[0] for r in rows], dtype=np.float64)
    y = np.array([r[1] for r in rows])
    slope, intercept = np.polyfit(x, y, 1)
    return float(slope), float(intercept)


def bench_scene(name: str, ox: Oxray, mts: dict[str, Mitsuba], args, out: Path) -> str:
    lines = [f"### {name}\n"]
    # The reference: the mean of an oxray render and a Mitsuba render, each of --ref-spp, both
    # unbiased and independent of the ladder's renders. Their difference is the check that the
    # two scenes agree; half of its mean square is the variance left in the reference (per
    # pixel and channel), subtracted from every ladder MSE below.
    print(f"[{name}] reference: oxray sobol and Mitsuba, {args.ref_spp} spp each", file=sys.stderr)
    ref_o, ref_t = ox.render(args.ref_spp, 1_000_000, "sobol")
    t0 = time.perf_counter()
    mt0 = next(iter(mts))
    ref_m = mts[mt0].converged(args.ref_spp, 2_000_000)
    ref_mt = time.perf_counter() - t0
    ref = (ref_o.astype(np.float64) + ref_m) / 2
    np.save(out / f"{slug(name)}-reference-oxray.npy", ref_o)
    np.save(out / f"{slug(name)}-reference-mitsuba.npy", ref_m)
    unlit = np.all(ref < 1.0, axis=-1)
    ref_var = (rmse(ref_o, ref_m) ** 2 / 4, rmse(ref_o, ref_m, unlit) ** 2 / 4)
    mean_o, mean_m = ref_o.reshape(-1, 3).mean(0), ref_m.reshape(-1, 3).mean(0)
    # The mean's standard error from the per-pixel differences (pixels are nearly independent).
    diff = (ref_m.astype(np.float64) - ref_o).reshape(-1, 3)
    z = diff.mean(0) / (diff.std(0) / math.sqrt(len(diff)))
    h, w = ref.shape[:2]
    b = 16  # blocks of 16x16 pixels: a misplaced wall or a wrong colour shows beyond the noise
    bo = ref_o[: h // b * b, : w // b * b].reshape(h // b, b, w // b, b, 3).mean((1, 3))
    bm = ref_m[: h // b * b, : w // b * b].reshape(h // b, b, w // b, b, 3).mean((1, 3))
    block_rel = np.abs(bm - bo) / np.maximum(bo, 0.02)
    lines.append(f"Agreement: oxray (sobol, {args.ref_spp} spp, {ref_t:.1f} s) against {mt0} "
                 f"({args.ref_spp} spp, {ref_mt:.1f} s); their mean is the reference.\n")
    lines.append("| | R | G | B |\n|---|---|---|---|")
    lines.append("| image mean, oxray | " + " | ".join(f"{v:.5f}" for v in mean_o) + " |")
    lines.append("| image mean, Mitsuba | " + " | ".join(f"{v:.5f}" for v in mean_m) + " |")
    lines.append("| Mitsuba / oxray - 1 | " + " | ".join(f"{100 * v:+.3f} %" for v in (mean_m - mean_o) / mean_o) + " |")
    lines.append("| difference / its standard error | " + " | ".join(f"{v:+.2f}" for v in z) + " |")
    lines.append(f"\n16x16-pixel block means: median |Mitsuba - oxray| "
                 f"{100 * float(np.median(block_rel)):.2f} %, largest {100 * float(block_rel.max()):.2f} % "
                 f"(relative to max(block mean, 0.02)). Variance left in the reference, subtracted "
                 f"from the MSEs: {ref_var[0]:.3g} (all pixels), {ref_var[1]:.3g} (below 1).\n")

    renderers = {f"oxray {s}": args.ladder for s in args.samplers}
    for r in mts:
        renderers[r] = args.ladder + [4 * args.ladder[-1]]
    results: dict[str, dict[int, list]] = {r: {} for r in renderers}
    for rep in range(args.repeats):
        for spp in renderers[mt0]:
            for r, ladder in renderers.items():
                if spp not in ladder:
                    continue
                seed = 1000 * rep + spp
                if r in mts:
                    img, t = mts[r].render(spp, seed)
                else:
                    img, t = ox.render(spp, seed, r.split()[1])
                results[r].setdefault(spp, []).append(
                    (t, rmse(img, ref) ** 2 - ref_var[0], rmse(img, ref, unlit) ** 2 - ref_var[1]))
                print(f"[{name}] run {rep} {r:17} {spp:5} spp {t:8.3f} s  RMSE {rmse(img, ref):.5f}",
                      file=sys.stderr)
    # Per renderer and spp: the median time, the RMSE as the root of the mean MSE over the runs.
    curves = {r: {spp: (statistics.median(v[0] for v in vals),
                        math.sqrt(max(statistics.fmean(v[1] for v in vals), 0.0)),
                        math.sqrt(max(statistics.fmean(v[2] for v in vals), 0.0)))
                  for spp, vals in per.items()} for r, per in results.items()}
    (out / f"{slug(name)}-curves.json").write_text(json.dumps(curves, indent=1))
    lines.append(f"Renders ({args.repeats} runs of each, alternating renderers; the median time; "
                 "the RMSE over the runs):\n")
    lines.append("| renderer | spp | time s | RMSE, all pixels | RMSE, below 1 |\n|---|---|---|---|---|")
    for r in renderers:
        for spp, (t, e, eu) in sorted(curves[r].items()):
            lines.append(f"| {r} | {spp} | {t:.3f} | {e:.5f} | {eu:.5f} |")
    w, h = (int(v) for v in args.size.split("x"))
    fits = {r: fit_time_per_spp([(s, c[0]) for s, c in curves[r].items()]) for r in renderers}
    slope = {r: f[0] for r, f in fits.items()}
    lines.append("\nCost per sample (the slope of a line fitted to time over spp; its intercept is "
                 "a fixed cost per render):\n")
    lines.append(f"| renderer | ms per spp | M samples/s | time per sample / {mt0}'s | intercept s |"
                 "\n|---|---|---|---|---|")
    for r in renderers:
        lines.append(f"| {r} | {1e3 * slope[r]:.2f} | {w * h / slope[r] / 1e6:.2f} | "
                     f"{slope[r] / slope[mt0]:.2f} | {fits[r][1]:.3f} |")
    oxrays = [r for r in renderers if r not in mts]
    pairs = [(o, m) for o in oxrays for m in mts]
    for col, label in [(1, "all pixels"), (2, "pixels below 1 in the reference")]:
        lines.append(f"\nTime to equal RMSE ({label}), in seconds; ratios: oxray's time / "
                     "Mitsuba's (below 1: oxray is faster). Targets: the RMSEs that "
                     f"{oxrays[0]} reaches at the ladder's spp.\n")
        lines.append("| target RMSE | " + " | ".join(renderers) + " | "
                     + " | ".join(f"{o} / {m}" for o, m in pairs)
                     + " |\n|" + "---|" * (1 + len(renderers) + len(pairs)))
        for spp in args.ladder:
            target = curves[oxrays[0]][spp][col]
            at = {r: loglog_time_at([(c[0], c[col]) for c in curves[r].values()], target)
                  for r in renderers}
            cells = [f"{target:.5f}"] + ["n/a" if at[r] is None else f"{at[r]:.2f}" for r in renderers]
            cells += ["n/a" if at[o] is None or at[m] is None else f"**{at[o] / at[m]:.2f}**"
                      for o, m in pairs]
            lines.append("| " + " | ".join(cells) + " |")
    lines.append("")
    return "\n".join(lines)


def slug(name: str) -> str:
    return re.sub(r"[^a-z0-9]+", "-", name.lower()).strip("-")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--threads", type=int, default=2)
    ap.add_argument("--size", default="256x256")
    ap.add_argument("--max-depth", type=int, default=8)
    ap.add_argument("--ref-spp", type=int, default=2048)
    ap.add_argument("--ladder", default="4,16,64,256")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--samplers", default="sobol,independent", help="oxray's (--sampler)")
    ap.add_argument("--mitsuba-samplers", default="independent,ldsampler",
                    help="Mitsuba's sampler plugins; the first also renders the reference")
    ap.add_argument("--mitsuba-rr-depth", type=int, default=5,
                    help="Mitsuba's rr_depth (its default, 5)")
    ap.add_argument("--scenes", default="cornell,gltf")
    ap.add_argument("--gltf", type=Path, default=ROOT.parent / "shared/data/gltf/balloon/scene.gltf")
    ap.add_argument("--out", type=Path, default=ROOT / "target/bench-mitsuba")
    ap.add_argument("--oxray", type=Path, default=None,
                    help="an oxray binary to measure (default: build and use target/release/oxray)")
    args = ap.parse_args()
    args.ladder = [int(v) for v in args.ladder.split(",")]
    args.samplers = args.samplers.split(",")
    args.mitsuba_samplers = args.mitsuba_samplers.split(",")
    args.out.mkdir(parents=True, exist_ok=True)
    if args.oxray is None:
        subprocess.run(["cargo", "build", "--release", "-q", "-p", "oxray-cli"], cwd=ROOT,
                       check=True)
    exe = args.oxray or ROOT / "target/release/oxray"
    version = subprocess.run([str(exe), "--version"], capture_output=True, text=True).stdout.strip()
    commit = subprocess.run(["git", "describe", "--always", "--dirty"], cwd=ROOT,
                            capture_output=True, text=True).stdout.strip()
    if args.oxray is not None:
        commit = f"binary {args.oxray}, scripts of {commit}"
    cpu = next((l.split(":", 1)[1].strip() for l in open("/proc/cpuinfo") if l.startswith("model name")), "?")
    llvm = os.environ.get("DRJIT_LIBLLVM_PATH", "")
    load = os.getloadavg()[0]
    report = [f"## oxray against Mitsuba 3 at equal error\n",
              f"{version} (commit {commit}); Mitsuba {mi.__version__}, Dr.Jit {dr.__version__}, "
              f"variant {VARIANT}" + (f" ({Path(llvm).name})" if llvm else " (no LLVM: scalar fallback)")
              + f"; {cpu}, {os.cpu_count()} CPUs; {args.threads} threads each; {args.size}, "
              f"max depth {args.max_depth}, Mitsuba's rr_depth {args.mitsuba_rr_depth}, box filter; load average {load:.1f} at the start.\n"]
    if VARIANT != "llvm_ad_rgb":
        report.append("**Mitsuba runs its scalar variant: the LLVM backend is unavailable.**\n")
    with tempfile.TemporaryDirectory() as tmpdir:
        tmp = Path(tmpdir)
        w, h = (int(v) for v in args.size.split("x"))
        for scene in args.scenes.split(","):
            if scene == "cornell":
                meshes, camera = cornell_geometry()
                mts = {f"Mitsuba {s}": Mitsuba(mitsuba_scene(
                    meshes, CORNELL_ALBEDO, camera, (w, h), args.max_depth, tmp,
                    emitter={"light": CORNELL_RADIANCE}, sampler=s,
                    rr_depth=args.mitsuba_rr_depth), args.threads)
                    for s in args.mitsuba_samplers}
                ox = Oxray(exe, [], args.size, args.max_depth, args.threads, tmp)
                report.append(bench_scene("Cornell box", ox, mts, args, args.out))
            elif scene == "gltf":
                if not args.gltf.is_file():
                    report.append(f"### glTF\n\nSkipped: {args.gltf} is absent.\n")
                    continue
                meshes, albedo, camera = gltf_geometry(args.gltf)
                obj = tmp / "scene.obj"
                write_obj(obj, meshes, albedo)
                mts = {f"Mitsuba {s}": Mitsuba(mitsuba_scene(
                    meshes, albedo, camera, (w, h), args.max_depth, tmp, env=1.0, sampler=s,
                    rr_depth=args.mitsuba_rr_depth),
                    args.threads) for s in args.mitsuba_samplers}
                ox = Oxray(exe, [str(obj), "--env", "1",
                                 "--look-from", ",".join(f"{v:.9g}" for v in camera["origin"]),
                                 "--look-at", ",".join(f"{v:.9g}" for v in camera["target"]),
                                 "--up", "0,1,0", "--fov", f"{camera['fov']}"],
                           args.size, args.max_depth, args.threads, tmp)
                ntri = sum(len(t) for _, t in meshes.values())
                label = f"glTF: {args.gltf.parent.name} ({ntri} triangles, {len(meshes)} materials)"
                report.append(bench_scene(label, ox, mts, args, args.out))
            else:
                raise SystemExit(f"unknown scene {scene!r}")
    text = "\n".join(report)
    (args.out / "report.md").write_text(text)
    print(text)


if __name__ == "__main__":
    main()
