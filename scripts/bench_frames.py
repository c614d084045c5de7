"""Frames, by part: frames per second from images end to end against a baseline
checkout, the augmented training pipeline, the descriptor network by batch size,
the descriptors on Nordland, and the augmentations alone.

python scripts/bench_frames.py end-to-end --base /tmp/base [--repeats 2]  # frames
python scripts/bench_frames.py first-run [--base /tmp/base] [--frames 111]
python scripts/bench_frames.py pipeline [--frames 1024] [--descriptor patchnorm]
python scripts/bench_frames.py network [--batches 1 2 4 8 16 32 64] [--frames 512]
python scripts/bench_frames.py descriptors      # reports/descriptors.*
python scripts/bench_frames.py augment          # reports/augment.*

The package is imported inside the functions: ``end-to-end`` runs this module's
:func:`augmented` in a baseline checkout too, whose layout may differ.
"""

import itertools
import json
import os
import shutil
import tempfile
from pathlib import Path

import _harness as h
import numpy as np

PARTIAL = Path(tempfile.gettempdir()) / "bench_frames_partial.json"
QUICK_FRAMES = dict(frames=100, repeats=1, aug_frames=130)  # --quick


def augmented(root: str, frames: int, names: str) -> dict:
    """An augmented job's process, in either checkout: one Lite0 epoch, frames/s."""
    _, features, images, _ = library()
    x = images.nordland(root, seasons=("summer",), progress=False)[0].images[:frames]
    desc = features.get_descriptor("efficientnet_lite0")
    if features.__name__ == "rhythmic_jax.frames.features":  # not the baseline
        from rhythmic_jax.frames.compiled import CompilePolicy, FastDescriptor

        desc = FastDescriptor(desc, frames, CompilePolicy(min_frames=0))
    tm = epochs(x, desc, "bench", [(names,)])[0]
    return dict(tm, frames_per_s=len(x) / tm["wall"])


def make_folders(root: Path, tmp: Path, n: int, small: int = 100) -> dict[str, Path]:
    """640x320 JPEG folders: ref (n summer frames), q (n winter), small (100)."""
    from PIL import Image

    summer, winter = h.nordland_images(root)
    out = {}
    for name, frames in (("ref", summer.images[:n]), ("q", winter.images[:n]),
                         ("small", summer.images[n : n + small])):  # fmt: skip
        if not frames.size:
            continue
        folder = tmp / name
        folder.mkdir()
        for i, im in enumerate(frames):
            big = Image.fromarray(im).resize((640, 320), Image.BICUBIC)
            big.save(folder / f"frame{i:05d}.jpg", quality=90)
        out[name] = folder
    return out


def timed_run(cmd: list[str], checkout: str, cache: Path) -> dict:
    """Wall and CPU seconds of one command of ``checkout`` with its cache folder."""
    env = h.job_env() | {"RHYTHMIC_JAX_CACHE": str(cache)}
    r = h.child(cmd, checkout, h.weights_folder(), env=env)
    return r | dict(stdout=r["stdout"][-2000:], stderr=r["stderr"][-500:])


OPTIONS_FRAMES = dict(base=(Path, "baseline checkout (to measure)"), frames=1000,
                      repeats=2, aug_frames=256, skip_augmented=False)  # fmt: skip


def job_cmd(job: str, variant: str, tmp: Path, folders: dict, args) -> list[str]:
    """One job's command line (each checkout's own command-line module)."""
    if job.startswith("augmented"):
        root = str(args.root / "nordland_64x32")
        return h.command(augmented, root, args.aug_frames, job[10:])
    exe, out_map = h.CLI, tmp / f"{variant}.map"
    if job == "query":
        out = str(tmp / f"{variant}.npy")
        return [*exe, "query", str(out_map), str(folders["q"]), "--out", out,
                "--no-progress"]  # fmt: skip
    if job == "fit100":
        out_map = tmp / f"{variant}_small.map"
    shutil.rmtree(out_map, ignore_errors=True)
    src = folders["ref" if job == "fit" else "small"]
    return [*exe, "fit", str(src), "--out", str(out_map), "--descriptor",
            "efficientnet_lite0", "--no-progress"]  # fmt: skip


def run_frames(args) -> dict:
    """Frames/s from images end to end against a baseline (frames)."""
    if args.base is None:
        raise SystemExit("--base (a baseline checkout) is needed to measure")
    paths = {k: str(v) for k, v in h.checkouts(args.base).items()}
    jobs = ["fit", "query", "fit100"]
    jobs += [] if args.skip_augmented else ["augmented_none", "augmented_all"]
    with tempfile.TemporaryDirectory(prefix="bench_frames") as tmpdir:
        tmp = Path(tmpdir)
        folders = make_folders(args.root, tmp, args.frames)
        warm = tmp / "warm"  # the new checkout's compiled network, built once
        cmd = job_cmd("fit100", "warm", tmp, folders, args) + ["--compile", "always"]
        built = timed_run(cmd, paths["new"], warm)
        for job in ("fit", "query"):  # the first 1000-frame jobs compile the programs
            timed_run(job_cmd(job, "first", tmp, folders, args), paths["new"], warm)
        runs: dict[str, dict[str, list]] = {}
        for rep in range(args.repeats):
            # alternate which side goes first, so drifting load hits both alike
            for variant in ("base", "new") if rep % 2 == 0 else ("new", "base"):
                for job in jobs:
                    # an empty descriptor cache; the new checkout's holds the warm
                    # one's network and compiled programs (a second job)
                    new = warm if variant == "new" else None
                    cache = h.fresh_cache(tmp, new, ("compiled", "jax"))
                    cmd = job_cmd(job, variant, tmp, folders, args)
                    r = timed_run(cmd, paths[variant], cache)
                    if job.startswith("augmented"):
                        r["inner"] = json.loads(r["stdout"].strip().splitlines()[-1])
                    print(variant, job, rep, round(r["wall"], 1), r["load"], flush=True)
                    runs.setdefault(job, {}).setdefault(variant, []).append(r)
                    PARTIAL.write_text(json.dumps(runs))
        pred = {v: np.load(tmp / f"{v}.npy") for v in ("base", "new")}
        agree = float((pred["base"] == pred["new"]).mean())
        # winter frame i was taken at summer frame i's place
        within = {v: float((np.abs(p - np.arange(len(p))) <= 2).mean())
                  for v, p in pred.items()}  # fmt: skip
    report = dict(
        base=paths["base"], frames=args.frames, aug_frames=args.aug_frames,
        repeats=args.repeats, build_compiled=dict(wall=built["wall"], cpu=built["cpu"]),
        prediction_agreement=agree, prediction_within_2=within, runs=runs,
    )  # fmt: skip
    report["summary"] = summary_frames(report)
    return report


# job -> the smallest new / base frames/s ratio asked for
TARGETS = dict(fit=2.0, query=3.0, fit100=1 / 1.15, augmented_none=2.5,
               augmented_all=2.5)  # fmt: skip


def summary_frames(report: dict) -> dict:
    """Per job: each checkout's median wall, CPU and frames/s; speedup, target."""
    out = {}
    for job, by in report["runs"].items():
        row, frames = {}, 100 if job == "fit100" else report["frames"]
        for variant, rs in by.items():
            fps = [r["inner"]["frames_per_s"] if job.startswith("augmented")
                   else frames / r["wall"] for r in rs]  # fmt: skip
            med = {k: float(np.median([r[k] for r in rs])) for k in ("wall", "cpu")}
            row[variant] = med | dict(frames_per_s=float(np.median(fps)))
        speedup = row["new"]["frames_per_s"] / row["base"]["frames_per_s"]
        need = TARGETS[job]
        out[job] = row | dict(speedup=speedup, target=need, met=bool(speedup >= need))
    return out


markdown_frames = h.markdown(
    "Frames per second from images, end to end",
    "The baseline checkout interleaved with this one, each job a fresh process with an"
    " empty descriptor cache (the new one's compiled network built before:"
    " build_compiled); medians in the summary; the target is on frames/s.",
)


def library() -> tuple:
    """The augmented fit's modules here, or in a baseline checkout's flat layout."""
    try:
        from rhythmic_jax.augment import stream
        from rhythmic_jax.frames import features
        from rhythmic_jax.io import images
        from rhythmic_jax.solvers import newton
    except ImportError:
        from rhythmic_jax import augmented as stream
        from rhythmic_jax import data as images
        from rhythmic_jax import features, newton
    return stream, features, images, newton


def epochs(images, desc, key: str, variants, elastic="coarse") -> list[dict]:
    """Per variant, one augmented epoch from the clean fit after a compiling one:
    its seconds by part and its wall."""
    from rhythmic_jax.map.periods import candidate_periods
    from rhythmic_jax.solvers.objective import default_c, targets

    (stream, features, _, newton), n = library(), len(images)
    clean = features.cached_describe(images, desc, key=key, progress=False)
    periods, c, labels = candidate_periods(n, 2, 1, 7), default_c(n), np.arange(n)
    init, _ = newton.newton_fit(clean, targets(labels, periods), c, progress=False)
    plain = stream.AugmentedFit(names=("hflip",), p=0.0, epochs=1)

    def fit(x, cfg):
        m = len(x)
        args = x, clean[:m], labels[:m], periods, init, c, desc, cfg
        return stream.fit_augmented(*args, progress=False)[1]

    fit(images[:128], plain)
    out = []
    for names in variants:
        settings = {"elastic_impl": elastic}
        cfg = stream.AugmentedFit(names=names, epochs=1, augment_settings=settings)
        tm, wall, _ = h.timed(fit, images, plain if names == ("none",) else cfg)
        out.append(dict(tm, wall=wall))
    return out


OPTIONS_PIPELINE = dict(frames=1024, descriptor="patchnorm", threads=2,
                        elastic=dict(default="coarse", choices=("kornia", "coarse")))


def run_pipeline(args) -> dict:
    """Frames/s of the augmented training pipeline (pipeline)."""
    import torch

    from rhythmic_jax.augment.kornia_ops import NAMES
    from rhythmic_jax.frames.features import get_descriptor
    from rhythmic_jax.map.periods import candidate_periods

    torch.set_num_threads(args.threads)
    variants = [("none",), *((k,) for k in NAMES), ("all",)]
    if args.quick:
        args.frames, variants = min(args.frames, 160), [("none",), ("hflip",)]
    own = "" if args.descriptor == "patchnorm" else "_" + args.descriptor
    args.stem = "pipeline" + own + ("_quick" if args.quick else "")
    (summer,) = h.nordland_images(args.root, ("summer",))
    images, desc = summer.images[: args.frames], get_descriptor(args.descriptor)
    n, load0, rows = len(images), h.load_average(), []
    times = epochs(images, desc, f"nordland-summer-{n}", variants, args.elastic)
    for names, tm in zip(variants, times, strict=True):
        # n augmented frames: half the epoch's frames, so half its step time
        fps = n / (tm["augment"] + tm["describe"] + tm["step"] / 2)
        rows.append(dict(augmentation=names[0], frames_per_s=fps,
                         augment_s=tm["augment"], describe_s=tm["describe"],
                         step_s=tm["step"], wall_s=tm["wall"]))  # fmt: skip
    for r in rows:
        r["ratio_to_plain"] = r["frames_per_s"] / rows[0]["frames_per_s"]
    return dict(descriptor=desc.settings() | {"name": args.descriptor}, frames=n,
                templates=sum(candidate_periods(n, 2, 1, 7)),
                torch_threads=torch.get_num_threads(), loadavg_start=load0,
                loadavg_end=h.load_average(), rows=rows)  # fmt: skip


markdown_pipeline = h.markdown(
    "Augmented training pipeline",
    "Augmented frames through augmentation, descriptor, DLPack and the optax step (half"
    " the epoch's step time).",
)


QUICK_NETWORK = dict(batches=[8], frames=64, repeats=1)  # --quick


def frames_per_s(run, x, repeats: int) -> dict:
    """Best and median frames/s of ``run`` over ``x`` (m, 3, h, w), and CPU/wall."""
    run(x[: 2 * max(1, len(x) // 64)])  # warm-up
    t = h.walls(lambda: run(x), repeats)
    return dict(best=len(x) / t["best"], median=len(x) / t["median"],
                cpu_per_wall=t["cpu_per_wall"])  # fmt: skip


OPTIONS_NETWORK = dict(batches=[1, 2, 4, 8, 16, 32, 64], frames=512, repeats=3,
                       block=10)  # fmt: skip


def run_network(args) -> dict:
    """The descriptor network's frames/s by batch size (network)."""
    import torch

    from rhythmic_jax.frames import compiled
    from rhythmic_jax.frames.features import get_descriptor
    from rhythmic_jax.frames.pipeline import _to_batch

    desc = get_descriptor("efficientnet_lite0", block=args.block)
    images = h.nordland_images(args.root, ("summer",))[0].images[: args.frames]
    with torch.inference_mode():
        x, net = desc.prepare(_to_batch(images)), desc.network().eval()
        reference, rows = net(x[:64]).numpy(), []
        with tempfile.TemporaryDirectory(prefix="bench_network") as cache:
            for b in args.batches:
                eager = frames_per_s(compiled.Sliced(net, b), x, args.repeats)
                shape = (b, 3, desc.height, desc.width)
                fn, build, _ = h.timed(compiled._compiled, desc, shape, cache)
                if fn is None:
                    raise RuntimeError("the network could not be compiled here")
                run = compiled._chunked(fn, b)
                fast = frames_per_s(run, x, args.repeats)
                diff = np.linalg.norm(run(x[:64]).numpy() - reference, axis=1).max()
                row = dict(batch=b, eager=eager, compiled=fast, build_s=build,
                           max_rel_diff=float(diff))  # fmt: skip
                h.log.info("%s", row)
                rows.append(row)
    return dict(descriptor=desc.name,
                settings=dict(block=args.block, width=desc.width, height=desc.height),
                frames=len(x), repeats=args.repeats, job_batch=compiled.COMPILE_BATCH,
                job_eager_batch=compiled.EAGER_BATCH, rows=rows)  # fmt: skip


markdown_network = h.markdown(
    "The descriptor network's frames/s by batch size",
    "Best and median frames/s after a warm-up. compiled: an AOTInductor package per"
    " batch (build_s); eager: the module on slices; max_rel_diff: compiled vs eager.",
)


# (row label, registry name, settings)
DESCRIPTORS = (
    ("patchnorm 64x32", "patchnorm", {}),
    ("hog 64x32", "hog", {}),
    ("efficientnet_lite0 b10 224x112", "efficientnet_lite0", {}),
    ("efficientnet_lite0 b10 224x224", "efficientnet_lite0", {"height": 224}),
)
PCA_OF = "efficientnet_lite0 b10 224x112"


def recall_at_1(queries: np.ndarray, reference: np.ndarray) -> tuple[float, float]:
    """Unit-norm rows; ground truth is the same index. (exact, within +-1)."""
    err = np.abs(np.argmax(queries @ reference.T, axis=1) - np.arange(len(queries)))
    return float(np.mean(err == 0)), float(np.mean(err <= 1))


def run_descriptors(args) -> dict:
    """Descriptors on Nordland, winter against summer (descriptors)."""
    import torch

    from rhythmic_jax.frames.features import cached_describe, describe, get_descriptor
    from rhythmic_jax.map.projection import fit_pca, project

    torch.set_num_threads(args.threads)
    trav = h.nordland_images(args.root, progress=args.progress)
    summer, winter = (t.images for t in trav)
    if args.quick:
        summer, winter = summer[:300], winter[:300]
        args.timing_frames = min(args.timing_frames, 32)
    timing = np.concatenate([summer[::20], winter[::20]])[: args.timing_frames]
    h.log.info("summer %s, winter %s, timing on %d frames", summer.shape, winter.shape,
             len(timing))  # fmt: skip
    rows, kept = [], {}
    kw = dict(cache_dir=args.cache_dir, batch_size=args.batch_size)
    for label, name, settings in DESCRIPTORS[:1] if args.quick else DESCRIPTORS:
        d = get_descriptor(name, **settings)
        key = "nordland64x32-" + (f"first{len(summer)}-" if args.quick else "")
        ref = cached_describe(summer, d, key + "summer", progress=args.progress, **kw)
        qry = cached_describe(winter, d, key + "winter", progress=args.progress, **kw)
        exact, tol1 = recall_at_1(qry, ref)
        describe(timing[: args.batch_size], d, args.batch_size)  # warm-up
        fps = len(timing) / h.timed(describe, timing, d, args.batch_size)[1]
        rows.append(dict(descriptor=label, name=name, settings=d.settings(), dim=d.dim,
                         recall_at_1=exact, recall_at_1_tol1=tol1,
                         frames_per_s=fps))  # fmt: skip
        h.log.info("%s: recall@1 %.4f (+-1: %.4f), %.1f frames/s", label, exact, tol1,
                 fps)  # fmt: skip
        kept[label] = (ref, qry, fps)
    ref, qry, fps = kept.get(PCA_OF) or next(iter(kept.values()))
    args.pca_dim = min(args.pca_dim, ref.shape[1] // 2, len(ref) - 1)
    pca, fit_s, _ = h.timed(fit_pca, ref, args.pca_dim)
    qp, rp = (np.asarray(project(pca, x, normalize=True)) for x in (qry, ref))
    exact, tol1 = recall_at_1(qp, rp)
    of = PCA_OF if PCA_OF in kept else next(iter(kept))
    settings = dict(of=of, k=args.pca_dim, fit_on="summer", fit_s=round(fit_s, 2))
    rows.append(dict(descriptor=f"PCA-{args.pca_dim} of {of}", name="pca",
                     settings=settings, dim=args.pca_dim, recall_at_1=exact,
                     recall_at_1_tol1=tol1, frames_per_s=fps))  # fmt: skip
    h.log.info("PCA-%d: recall@1 %.4f (+-1: %.4f), fit %.1f s", args.pca_dim, exact,
             tol1, fit_s)  # fmt: skip
    return dict(dataset="nordland_64x32: winter queries vs summer map",
                n_reference=len(summer), n_queries=len(winter),
                metric="cosine, brute force", timing_frames=len(timing),
                torch_threads=args.threads, results=rows)  # fmt: skip


markdown_descriptors = h.markdown(
    "Descriptors on Nordland 64x32 (winter queries vs summer map)",
    "Brute-force cosine nearest neighbour; recall_at_1_tol1 within one index.",
)


OPTIONS_DESCRIPTORS = dict(cache_dir=Path, threads=os.cpu_count() or 1, batch_size=64,
                           timing_frames=256, pca_dim=512)  # fmt: skip


SIZES = ((32, 64), (112, 224), (224, 224))  # (H, W)
QUICK_AUGMENT = dict(batch=8, repeats=1)  # --quick


def augment_cases() -> list[tuple]:
    """(label, config) of every timed pipeline."""
    from rhythmic_jax.augment.kornia_ops import NAMES, AugmentConfig

    coarse = dict(elastic_impl="coarse")
    return [(name, AugmentConfig((name,), p=1.0)) for name in NAMES] + [
        ("elastic (coarse)", AugmentConfig(("elastic",), 1.0, **coarse)),
        ("all seven (kornia elastic)", AugmentConfig(("all",), p=1.0)),
        ("all seven (coarse elastic)", AugmentConfig(("all",), 1.0, **coarse)),
    ]


def time_augment(batch, config, repeats: int, min_s=0.2) -> dict:
    """Best and median seconds per call of ``augment`` on ``batch``."""
    from rhythmic_jax.augment.kornia_ops import augment

    seeds = itertools.count()  # a new draw each call
    _, first, _ = h.timed(augment, batch, config, seed=next(seeds))  # warm-up
    calls = max(1, round(min_s / first))  # each repeat's calls take >= min_s
    return h.walls(lambda: augment(batch, config, seed=next(seeds)), repeats, calls)


OPTIONS_AUGMENT = dict(batch=64, repeats=5, threads=[2])


def run_augment(args) -> dict:
    """Frames/s of each augmentation and of all seven (augment)."""
    import torch

    generator, rows = torch.Generator().manual_seed(0), []
    for threads in args.threads:
        torch.set_num_threads(threads)
        for height, w in SIZES[:1] if args.quick else SIZES:
            batch = torch.rand(args.batch, 3, height, w, generator=generator)
            for label, config in augment_cases():
                t = time_augment(batch, config, args.repeats)
                fps = args.batch / t["best"]
                rows.append(dict(op=label, size=f"{w}x{height}", threads=threads,
                                 fps_best=fps, fps_median=args.batch / t["median"]))
                print(f"{threads}t {w}x{height:<4} {label:<28} {fps:9.0f} frames/s")
    return dict(batch=args.batch, repeats=args.repeats, torch_threads=args.threads,
                rows=rows)  # fmt: skip


OPTIONS_FIRST = dict(base=(Path, "baseline checkout (its first run, optional)"),
                     frames=111, repeats=2, build_timeout=900.0)  # fmt: skip


def wait_for_builder(cache: Path, timeout: float) -> dict:
    """Wait for the background build a first job queued at its exit: seconds until
    its lock under ``cache``/compiled is gone (at most ``timeout``) and whether the
    package is there; no lock within 10 s: no build."""
    import time

    folder, t0 = cache / "compiled", time.perf_counter()
    while not list(folder.glob("*.lock")) and time.perf_counter() - t0 < 10:
        time.sleep(0.2)
    while list(folder.glob("*.lock")):
        if time.perf_counter() - t0 > timeout:
            raise RuntimeError(f"the background build in {cache} ran past {timeout} s")
        time.sleep(0.5)
    built = [p for p in folder.glob("*.pt2") if ".tmp" not in p.name]
    return dict(seconds=time.perf_counter() - t0, built=bool(built))


def run_first(args) -> dict:
    """A machine's first deep-descriptor job: eager alone, first and second run."""
    paths = {k: str(v) for k, v in h.checkouts(args.base).items()}
    runs: dict[str, list] = {}
    with tempfile.TemporaryDirectory(prefix="bench_first") as tmpdir:
        tmp = Path(tmpdir)
        src = make_folders(args.root, tmp, args.frames, small=0)["ref"]

        def describe(checkout: str, cache: Path, *extra) -> dict:
            out = tmp / "out.npy"
            cmd = [*h.CLI, "describe", str(src), "--descriptor", "efficientnet_lite0",
                   "--out", str(out), "--no-progress", *extra]  # fmt: skip
            r = timed_run(cmd, checkout, cache)
            return r | dict(frames_per_s=args.frames / r["wall"])

        for rep in range(args.repeats):
            order = list(paths.items()) if rep % 2 == 0 else list(paths.items())[::-1]
            for variant, checkout in order:
                cache = h.fresh_cache(tmp)
                eager = describe(checkout, cache, "--compile", "never")
                cache = h.fresh_cache(tmp)
                first = describe(checkout, cache)
                first["builder_after"] = wait_for_builder(cache, args.build_timeout)
                # the next job: the compiled network and programs, no descriptors
                warm = h.fresh_cache(tmp, cache, ("compiled", "jax"))
                second = describe(checkout, warm)
                for name, r in (("eager", eager), ("first", first), ("second", second)):
                    runs.setdefault(f"{variant}/{name}", []).append(r)
                    print(variant, name, rep, round(r["wall"], 1), r["load"])
    summary = {}
    for key, rs in runs.items():
        summary[key] = dict(
            wall=float(np.median([r["wall"] for r in rs])),
            frames_per_s=float(np.median([r["frames_per_s"] for r in rs])),
            load=[r["load"] for r in rs])  # fmt: skip
    for variant in paths:
        first, eager = summary[f"{variant}/first"], summary[f"{variant}/eager"]
        first["of_eager"] = first["frames_per_s"] / eager["frames_per_s"]
    base = paths.get("base")
    return dict(frames=args.frames, repeats=args.repeats, base=base,
                base_commit=base and h.git_commit(Path(base)), summary=summary,
                runs=runs)  # fmt: skip


markdown_first = h.markdown(
    "A machine's first deep-descriptor job (EfficientNet-Lite0, 640x320 JPEG)",
    "Each run a fresh process. eager: --compile never, empty cache. first: the"
    " default, empty cache (no compiled network yet). second: the default again, once"
    " the build the first run asked for is over. of_eager: first frames/s over eager"
    " frames/s in the same checkout; medians of the repeats, checkouts alternated.",
)


markdown_augment = h.markdown(
    "Augmentation throughput (frames/s, CPU)",
    "p = 1; fps_best and fps_median of the repeats, each >= 0.2 s of calls.",
)


PARTS = {
    "end-to-end": h.Part(run_frames, markdown_frames, OPTIONS_FRAMES, "frames",
                         QUICK_FRAMES),  # fmt: skip
    "first-run": h.Part(run_first, markdown_first, OPTIONS_FIRST, "first_run"),
    "pipeline": h.Part(run_pipeline, markdown_pipeline, OPTIONS_PIPELINE, "pipeline"),
    "network": h.Part(run_network, markdown_network, OPTIONS_NETWORK, "network",
                      QUICK_NETWORK),  # fmt: skip
    "descriptors": h.Part(run_descriptors, markdown_descriptors, OPTIONS_DESCRIPTORS,
                          "descriptors"),  # fmt: skip
    "augment": h.Part(run_augment, markdown_augment, OPTIONS_AUGMENT, "augment",
                      QUICK_AUGMENT),  # fmt: skip
}

if __name__ == "__main__":
    h.main(__doc__, PARTS)
