"""Frames per second from images, end to end: this checkout against a baseline one.

python scripts/bench_frames.py --base /tmp/base [--repeats 2]
"""

import json
import shutil
import tempfile
from pathlib import Path

import _harness as h
import numpy as np

PARTIAL = Path(tempfile.gettempdir()) / "bench_frames_partial.json"
QUICK = dict(frames=100, repeats=1, aug_frames=130)  # --quick


def augmented(root: str, frames: int, names: str) -> dict:
    """An augmented job's process, in either checkout: one epoch over ``frames``
    Nordland frames with Lite0 (``none``: no augmentation) and its frames/s."""
    from bench_pipeline import epochs, library

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


def options(ap) -> None:
    ap.add_argument("--base", type=Path, required=True, help="baseline checkout")
    ap.add_argument("--frames", type=int, default=1000)
    ap.add_argument("--repeats", type=int, default=2)
    ap.add_argument("--aug-frames", type=int, default=256)
    ap.add_argument("--skip-augmented", action="store_true")


def job_cmd(job: str, variant: str, tmp: Path, folders: dict, args) -> list[str]:
    """One job's command line: each checkout's own command-line module
    (the installed script imports this checkout's)."""
    if job.startswith("augmented"):
        root = str(args.root / "nordland_64x32")
        return h.command(augmented, root, args.aug_frames, job[10:])
    exe, out_map = (
        h.CLI,
        tmp / f"{variant}.map",
    )
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


def run(args) -> dict:
    paths = {"base": str(args.base.resolve()), "new": str(h.REPO)}
    h.bytecode(*paths.values())
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
                    cache = Path(tempfile.mkdtemp(dir=tmp, prefix="cache"))
                    for kept in ("compiled", "jax") if variant == "new" else ():
                        if (warm / kept).is_dir():
                            shutil.copytree(warm / kept, cache / kept)
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
    report["summary"] = summary(report)
    return report


# job -> (smallest new/base frames/s ratio asked for, how the target reads)
TARGETS = {
    "fit": (2.0, "fit frames/s >= 2x"),
    "query": (3.0, "query frames/s >= 3x"),
    "fit100": (1 / 1.15, "100-frame fit no slower than 1.15x"),
    "augmented_none": (2.5, "augmented (none) frames/s >= 2.5x"),
    "augmented_all": (2.5, "augmented (all) frames/s >= 2.5x"),
}


def summary(report: dict) -> dict:
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
        need = TARGETS[job][0]
        out[job] = row | dict(speedup=speedup, target=need, met=bool(speedup >= need))
    return out


def markdown(report: dict) -> str:
    s = report["summary"]
    rows = [
        [job, s[job]["base"]["wall"], s[job]["new"]["wall"],
         s[job]["base"]["frames_per_s"], s[job]["new"]["frames_per_s"],
         s[job]["base"]["cpu"], s[job]["new"]["cpu"], f"{s[job]['speedup']:.2f}x",
         f"{s[job]['base']['cpu'] / s[job]['new']['cpu']:.2f}x",
         f"{TARGETS[job][1]}: {'met' if s[job]['met'] else 'not met'}"]
        for job in s
    ]  # fmt: skip
    loads = [r["load"] for by in report["runs"].values() for rs in by.values()
             for r in rs]  # fmt: skip
    within = report["prediction_within_2"]  # query within 2 frames of the true place
    return "\n".join([
        *h.header("Frames per second from images, end to end", report),
        f"Baseline checkout {report['base']} run interleaved with this one in"
        " the same process tree (CPU seconds count the work). Medians of"
        f" {report['repeats']} runs; every job starts with an empty descriptor"
        " cache. The new checkout's are second jobs: the compiled network was"
        f" built before (it took {report['build_compiled']['wall']:.0f} s wall in"
        " this run, in a 100-frame `--compile always` fit) and a first 1000-frame"
        " fit and query filled the compile cache; each job starts from a copy.",
        "",
        h.table(["job", "base wall s", "new wall s", "base frames/s",
               "new frames/s", "base CPU s", "new CPU s", "new / base frames/s",
               "base / new CPU s", "target (on frames/s)"],
              rows),  # fmt: skip
        "",
        "Jobs: a fresh `python -m rhythmic_jax.app.cli` of each checkout; `fit` and "
        "`query`"
        f" on {report['frames']} 640x320 JPEG frames (efficientnet_lite0); `fit100` on"
        f" 100; `augmented_*`: one epoch over {report['aug_frames']} Nordland frames,"
        " frames/s over the epoch. Under load, CPU-second ratios are the figure to"
        " expect on a quiet machine. The two query runs agree on"
        f" {100 * report['prediction_agreement']:.1f} % of predictions; within 2 frames"
        f" of the true place: base {100 * within['base']:.1f} %, new"
        f" {100 * within['new']:.1f} % (each checkout fits its own map and may choose"
        " other periods; winter queries on a summer map are the appearance change"
        " reports/cross_condition.md is about). 1-minute load average at the end of"
        f" each job: {min(loads):.1f} to {max(loads):.1f} (2 cores).",
    ])  # fmt: skip


if __name__ == "__main__":
    h.main(__doc__, run, markdown, options, stem="frames", quick=QUICK)
