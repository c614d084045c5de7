"""The descriptor network's frames/s by batch size, compiled against eager.

python scripts/bench_network.py [--batches 1 2 4 8 16 32 64] [--frames 512]
"""

import tempfile

import numpy as np
import torch
from _harness import header, log, main, nordland_images, table, timed

from rhythmic_jax.frames import compiled
from rhythmic_jax.frames.features import get_descriptor
from rhythmic_jax.frames.pipeline import _to_batch

HEAD = ["batch", "eager best f/s", "eager median f/s", "compiled best f/s",
        "compiled median f/s", "compiled / eager", "compiled CPU / wall", "build s",
        "max rel diff"]  # fmt: skip
QUICK = dict(batches=[8], frames=64, repeats=1)  # --quick


def frames_per_s(run, x: torch.Tensor, repeats: int) -> dict:
    """Best and median frames/s of ``run`` over ``x`` (m, 3, h, w), and CPU/wall."""
    run(x[: 2 * max(1, len(x) // 64)])  # warm-up
    walls, cpus = zip(*(timed(run, x)[1:] for _ in range(repeats)), strict=True)
    best = int(np.argmin(walls))
    return dict(best=len(x) / walls[best], median=len(x) / float(np.median(walls)),
                cpu_per_wall=cpus[best] / walls[best])  # fmt: skip


def options(ap) -> None:
    ap.add_argument("--batches", type=int, nargs="+", default=[1, 2, 4, 8, 16, 32, 64])
    ap.add_argument("--frames", type=int, default=512)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--block", type=int, default=10)


def run(args) -> dict:
    desc = get_descriptor("efficientnet_lite0", block=args.block)
    images = nordland_images(args.root, ("summer",))[0].images[: args.frames]
    with torch.inference_mode():
        x, net = desc.prepare(_to_batch(images)), desc.network().eval()
        reference, rows = net(x[:64]).numpy(), []
        with tempfile.TemporaryDirectory(prefix="bench_network") as cache:
            for b in args.batches:
                eager = frames_per_s(compiled.Sliced(net, b), x, args.repeats)
                shape = (b, 3, desc.height, desc.width)
                fn, build, _ = timed(compiled._compiled, desc, shape, cache)
                if fn is None:
                    raise RuntimeError("the network could not be compiled here")
                run = compiled._chunked(fn, b)
                fast = frames_per_s(run, x, args.repeats)
                diff = np.linalg.norm(run(x[:64]).numpy() - reference, axis=1).max()
                row = dict(batch=b, eager=eager, compiled=fast, build_s=build,
                           max_rel_diff=float(diff))  # fmt: skip
                log.info("%s", row)
                rows.append(row)
    return dict(descriptor=desc.name,
                settings=dict(block=args.block, width=desc.width, height=desc.height),
                frames=len(x), repeats=args.repeats, job_batch=compiled.COMPILE_BATCH,
                job_eager_batch=compiled.EAGER_BATCH, rows=rows)  # fmt: skip


def markdown(report: dict) -> str:
    s = report["settings"]
    rows = [
        [r["batch"], r["eager"]["best"], r["eager"]["median"],
         r["compiled"]["best"], r["compiled"]["median"],
         f"{r['compiled']['best'] / r['eager']['best']:.2f}x",
         r["compiled"]["cpu_per_wall"], r["build_s"], f"{r['max_rel_diff']:.1e}"]
        for r in report["rows"]
    ]  # fmt: skip
    best = max(report["rows"], key=lambda r: r["compiled"]["best"])
    eager = max(report["rows"], key=lambda r: r["eager"]["best"])
    by = {r["batch"]: r for r in report["rows"]}
    lines = header("The descriptor network's frames/s by batch size", report)
    lines += [
        f"{report['descriptor']} block {s['block']} at {s['width']}x{s['height']},"
        f" {report['frames']} Nordland frames prepared once (channels-last), each"
        f" figure the best (and median) of {report['repeats']} passes after a"
        " warm-up call. Compiled: an AOTInductor package built for that batch"
        " (weights frozen), the last chunk padded; eager: the module called on"
        " slices of that many frames. The rows are unit vectors, so the last"
        " column is the largest relative difference of compiled against eager.",
        "",
        table(HEAD, rows),
        "",
        f"Fastest compiled: batch {best['batch']} at"
        f" {best['compiled']['best']:.0f} frames/s; fastest eager: batch"
        f" {eager['batch']} at {eager['eager']['best']:.0f} frames/s.",
    ]
    job, job_eager = report["job_batch"], report.get("job_eager_batch")
    if job in by:
        lines.append(
            f"Jobs run the compiled network in batches of {job}"
            f" (`rhythmic_jax.frames.compiled.COMPILE_BATCH`,"
            f" {by[job]['compiled']['best']:.0f} frames/s here)"
        )
        if job_eager in by:
            lines[-1] += (
                f" and the eager one in batches of {job_eager}"
                f" (`EAGER_BATCH`, {by[job_eager]['eager']['best']:.0f} frames/s)"
            )
        lines[-1] += "."
    return "\n".join(lines)


if __name__ == "__main__":
    main(__doc__, run, markdown, options, stem="network", quick=QUICK)
