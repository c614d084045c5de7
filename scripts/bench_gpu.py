"""JAX's GPU against the same machine's CPU: fit, predict, batch and sequence decode.

python scripts/bench_gpu.py --write-features nordland_f16.npy
python scripts/bench_gpu.py --features nordland_f16.npy [--fit-sizes 20000 100000]
"""

from pathlib import Path

import jax
import numpy as np
from _harness import header, log, main, nordland_features, table, timed
from bench_scale import walk

from rhythmic_jax import RhythmicMap

QUICK = dict(rows=600, batches=[100], decode=2000, fit_sizes=[])  # --quick


def run_on(device, summer, winter, args) -> dict:
    """Every step of the report with ``device`` as JAX's default device."""
    out: dict = {"device": str(device), "kind": getattr(device, "device_kind", "")}
    rng = np.random.default_rng(0)

    def seconds(key, fn, *a, **kw):
        result, out[key], _ = timed(fn, *a, **kw)
        return result

    with jax.default_device(device):
        fit = lambda x, **kw: RhythmicMap(r=2, level=1, **kw).fit(x)  # noqa: E731
        seconds("fit_first_s", fit, summer)
        m = seconds("fit_second_s", fit, summer)
        out.update(periods=list(m.periods), self=m.predict(summer))
        out["winter"] = m.predict(winter)
        out["self_recall"] = float(np.mean(out["self"] == np.arange(len(summer))))
        out["predict_s"] = {b: timed(m.predict, winter[:b])[1] for b in args.batches}
        picks = rng.integers(0, len(winter), args.decode)
        noise = rng.normal(scale=0.01, size=(args.decode, winter.shape[1]))
        q = (winter[picks] + noise.astype(np.float32)).astype(np.float32)
        seconds("decode_first_s", m.predict, q)
        seconds("decode_s", m.predict, q)
        seq = dict(method="soft", sequence=args.length)
        seconds("sequence_first_s", m.predict, winter, **seq)
        seconds("sequence_s", m.predict, winter, **seq)
        d, sizes = summer.shape[1], args.fit_sizes
        out["fits_s"] = {n: timed(fit, walk(n, d, n), count=3)[1] for n in sizes}
    log.info("%s: %s", device, {k: v for k, v in out.items() if k[-1] == "s"})
    return out


def markdown(report: dict) -> str:
    gpu, cpu = report["gpu"], report["cpu"]
    name = gpu["kind"] if gpu else "no GPU"
    lines = header("JAX on a GPU against the same machine's CPU", report)
    if not gpu:
        lines += ["**No GPU was found: a CPU rehearsal, not the GPU report.**", ""]

    def row(label, key, sub=None):
        g, c = ("-" if not s else s[key] if sub is None else s[key][str(sub)]
                for s in (gpu, cpu))  # fmt: skip
        return [label, g, c, c / g if gpu and isinstance(g, float) and g > 0 else "-"]

    rows = [row("first fit, compile included (s)", "fit_first_s"),
            row("second fit, same shapes (s)", "fit_second_s")]  # fmt: skip
    rows += [row(f"predict {b} queries, first call (s)", "predict_s", b)
             for b in report["batches"]]  # fmt: skip
    rows += [row(f"decode {report['decode']:,} queries, warm (s)", "decode_s"),
             row(f"soft sequence decode L = {report['length']}, warm (s)",
                 "sequence_s")]  # fmt: skip
    rows += [row(f"fit {n:,} x {report['d']}, 3 candidates (s)", "fits_s", n)
             for n in report["fit_sizes"]]  # fmt: skip
    lines += [
        f"Nordland summer patchnorm {report['n']} x {report['d']}"
        f" (`{report['features']}`); GPU: {name}; CPU: {cpu['device']}.",
        "",
        table(["step", f"GPU ({name})", "CPU", "CPU / GPU"], rows),
        "",
    ]
    if gpu:
        lines.append(
            f"Predictions equal to the CPU's: self-query {report['equal_self']:.4f},"
            f" winter {report['equal_winter']:.4f} (self-query recall@1 "
            f"{gpu['self_recall']:.3f} GPU, {cpu['self_recall']:.3f} CPU)."
        )
    else:
        lines.append(f"CPU self-query recall@1 {cpu['self_recall']:.3f}.")
    return "\n".join(lines)


def options(ap) -> None:
    ap.add_argument("--features", type=Path, help="float16 (2, n, d) .npy")
    ap.add_argument("--write-features", type=Path, help="write that .npy and stop")
    ap.add_argument("--rows", type=int, default=None, help="first rows only")
    ap.add_argument("--batches", type=int, nargs="*", default=[100, 300, 700])
    ap.add_argument("--decode", type=int, default=100_000)
    ap.add_argument("--length", type=int, default=10)
    ap.add_argument("--fit-sizes", type=int, nargs="*", default=[20_000, 100_000])


def run(args) -> dict | None:
    if args.write_features:  # Nordland summer and winter patchnorm, float16 (2, n, d)
        from rhythmic_jax.io.atomic import save_npy

        both = np.stack(nordland_features(args.root)).astype(np.float16)
        save_npy(args.write_features, both)
        log.info("wrote %s %s", args.write_features, both.shape)
        return None
    if args.features is None:
        raise SystemExit("--features (or --write-features) is required")
    both = np.load(args.features)
    summer, winter = (np.asarray(x[: args.rows], np.float32) for x in both[:2])
    gpu = next((d for d in jax.devices() if d.platform == "gpu"), None)
    results = {"gpu": run_on(gpu, summer, winter, args) if gpu else None}
    results["cpu"] = run_on(jax.devices("cpu")[0], summer, winter, args)
    report = dict(
        features=str(args.features), n=len(summer), d=summer.shape[1],
        batches=args.batches, decode=args.decode, length=args.length,
        fit_sizes=args.fit_sizes,
        compilation_cache=str(jax.config.jax_compilation_cache_dir),
    )  # fmt: skip
    for key in ("self", "winter") if gpu else ():
        same = results["gpu"][key] == results["cpu"][key]
        report[f"equal_{key}"] = float(np.mean(same))
    for side in filter(None, results.values()):
        side.pop("self"), side.pop("winter")
    return report | results


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="gpu", quick=QUICK)
