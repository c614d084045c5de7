"""JAX's GPU against the same machine's CPU: fit, predict, batch and sequence decode.

python scripts/bench_gpu.py --write-features nordland_f16.npy
python scripts/bench_gpu.py --features nordland_f16.npy [--fit-sizes 20000 100000]
python scripts/bench_gpu.py --quick   # a CPU rehearsal on synthetic frames

Beside the in-process steps, each device's first calls in fresh processes: the
first fit and the first predict of each batch size, once with an empty compile
cache (cold) and once with the cache that run filled (warm), and ``rhythmic-jax
demo`` cold and warm. Programs compile with the library's compile options
(``rhythmic_jax.jit_options``; ``RHYTHMIC_JAX_GPU_AUTOTUNE=1`` measures XLA's
autotuner instead), stated in the report.
"""

import tempfile
from pathlib import Path

import _harness as h
import jax
import numpy as np
from bench_scale import walk

from rhythmic_jax import RhythmicMap
from rhythmic_jax.jit_options import describe

QUICK = dict(rows=600, batches=[100], decode=2000, fit_sizes=[2000])  # --quick


def first_calls(features: str, rows: int | None, batches: list[int]) -> dict:
    """Wall s of a fresh process's first fit and first predict of each batch."""
    from rhythmic_jax.jit_cache import enable_compile_cache

    enable_compile_cache()  # the folder $RHYTHMIC_JAX_COMPILE_CACHE names
    both = np.load(features)
    summer, winter = (np.asarray(x[:rows], np.float32) for x in both[:2])
    m, fit_s, _ = h.timed(RhythmicMap(r=2, level=1).fit, summer)
    predict = {b: h.timed(m.predict, winter[:b])[1] for b in batches}
    device = jax.devices()[0]
    return dict(fit_first_s=fit_s, predict_first_s=predict,
                device=getattr(device, "device_kind", str(device)))  # fmt: skip


def fresh(platform: str, args) -> dict:
    """:func:`first_calls` and the demo on ``platform``, cold then warm cache."""
    out: dict = {}
    with tempfile.TemporaryDirectory() as tmp:
        env = h.job_env(compile_cache=str(Path(tmp) / "jax"))
        for run in ("cold", "warm"):
            r = h.call(first_calls, str(args.features), args.rows, args.batches,
                       env=env, JAX_PLATFORMS=platform)  # fmt: skip
            out[run] = r["result"]
        demo = [*h.CLI, "demo", "--out", str(Path(tmp) / "demo"), "--no-progress"]
        demo += ["--quick"] if args.quick else []
        for run in ("cold", "warm"):
            r = h.child(demo, env=env, JAX_PLATFORMS=platform)
            out[run]["demo_s"], out[run]["demo_cpu_s"] = r["wall"], r["cpu"]
    h.log.info("%s fresh processes: %s", platform, out)
    return out


def run_on(device, summer, winter, args) -> dict:
    """Every step of the report with ``device`` as JAX's default device."""
    out: dict = {"device": str(device), "kind": getattr(device, "device_kind", "")}
    rng = np.random.default_rng(0)

    def seconds(key, fn, *a, **kw):
        result, out[key], _ = h.timed(fn, *a, **kw)
        return result

    with jax.default_device(device):
        fit = lambda x, **kw: RhythmicMap(r=2, level=1, **kw).fit(x)  # noqa: E731
        seconds("fit_first_s", fit, summer)
        m = seconds("fit_second_s", fit, summer)
        out.update(periods=list(m.periods), self=m.predict(summer))
        out["winter"] = m.predict(winter)
        out["self_recall"] = float(np.mean(out["self"] == np.arange(len(summer))))
        out["predict_s"] = {b: h.timed(m.predict, winter[:b])[1] for b in args.batches}
        picks = rng.integers(0, len(winter), args.decode)
        noise = rng.normal(scale=0.01, size=(args.decode, winter.shape[1]))
        q = (winter[picks] + noise.astype(np.float32)).astype(np.float32)
        seconds("decode_first_s", m.predict, q)
        seconds("decode_s", m.predict, q)
        seq = dict(method="soft", sequence=args.length)
        seconds("sequence_first_s", m.predict, winter, **seq)
        seconds("sequence_s", m.predict, winter, **seq)
        d, sizes = summer.shape[1], args.fit_sizes
        out["fits_first_s"], out["fits_s"] = {}, {}
        for n in sizes:  # the first call compiles; the second is the warm fit
            frames = walk(n, d, n)
            out["fits_first_s"][n] = h.timed(fit, frames, count=3)[1]
            out["fits_s"][n] = h.timed(fit, frames, count=3)[1]
    h.log.info("%s: %s", device, {k: v for k, v in out.items() if k[-1] == "s"})
    return out


markdown = h.markdown(
    "JAX on a GPU against the same machine's CPU",
    "Seconds per step and device (gpu: null, a CPU rehearsal); *_first_s compile."
    " fresh: first calls in fresh processes, compile cache empty (cold) or filled"
    " (warm); equal_*: GPU predictions equal to the CPU's.",
)


options = dict(
    features=(Path, "float16 (2, n, d) .npy"),
    write_features=(Path, "write that .npy and stop"), rows=(int, "first rows only"),
    batches=dict(type=int, nargs="*", default=[100, 300, 700]), decode=100_000,
    length=10, fit_sizes=dict(type=int, nargs="*", default=[20_000, 100_000]),
)  # fmt: skip


def run(args) -> dict | None:
    if args.write_features:  # Nordland summer and winter patchnorm, float16 (2, n, d)
        from rhythmic_jax.io.atomic import save_npy

        both = np.stack(h.nordland_features(args.root)).astype(np.float16)
        save_npy(args.write_features, both)
        h.log.info("wrote %s %s", args.write_features, both.shape)
        return None
    if args.features is None and args.quick:  # a rehearsal on synthetic frames
        args.features = Path(tempfile.mkdtemp()) / "walk_f16.npy"
        frames = walk(2 * args.rows, 256, 0)
        np.save(args.features, np.stack([frames[::2], frames[1::2]]).astype("f2"))
    if args.features is None:
        raise SystemExit("--features (or --write-features) is required")
    both = np.load(args.features)
    summer, winter = (np.asarray(x[: args.rows], np.float32) for x in both[:2])
    gpu = next((d for d in jax.devices() if d.platform == "gpu"), None)
    results = {"gpu": run_on(gpu, summer, winter, args) if gpu else None}
    results["cpu"] = run_on(jax.devices("cpu")[0], summer, winter, args)
    for side, platform in (("gpu", "cuda"), ("cpu", "cpu")):
        if results[side] is not None:
            results[side]["fresh"] = fresh(platform, args)
    report = dict(
        features=str(args.features), n=len(summer), d=summer.shape[1],
        batches=args.batches, decode=args.decode, length=args.length,
        fit_sizes=args.fit_sizes,
        compilation_cache=str(jax.config.jax_compilation_cache_dir),
        compile_options=describe(), demo=" --quick" if args.quick else "",
    )  # fmt: skip
    for key in ("self", "winter") if gpu else ():
        same = results["gpu"][key] == results["cpu"][key]
        report[f"equal_{key}"] = float(np.mean(same))
    for side in filter(None, results.values()):
        side.pop("self"), side.pop("winter")
    return report | results


PARTS = {"": h.Part(run, markdown, options, "gpu", QUICK)}  # one part: no subcommand

if __name__ == "__main__":
    h.main(__doc__, PARTS)
