"""The jobs that judge a map, or every representation, on queries: ``query``,
``evaluate`` and ``frontier`` (their options, defaults and rules, as
:mod:`rhythmic_jax.app.specs` declares every job's). Importing this module
imports no numpy, JAX or torch.
"""

from __future__ import annotations

from dataclasses import dataclass

from rhythmic_jax.app.options import Rule, like, option, part
from rhythmic_jax.app.parts import (
    GRIDS,
    GROUND_TRUTH_FORMATS,
    IGNORED,
    READS,
    RECALL_OVER,
    SELECTS,
    Job,
    Reading,
    grid_text,
    int_list,
    pair_list,
    recall_values,
    size_ok,
)
from rhythmic_jax.map.config import DECODERS
from rhythmic_jax.validate import int_option, number_option

__all__ = ["EvaluateJob", "FrontierJob", "QueryJob"]


SELECT = "only the queries of an hloc .h5 whose names start with PREFIX (query/)"


@dataclass(frozen=True)
class QueryJob(Job):
    """Queries of ``source`` to localise with the map at ``map``:
    ``rhythmic-jax query route.map q.npy --out pred.npy`` is
    ``query(QueryJob("route.map", "q.npy", out="pred.npy"))``; ``decode``,
    ``sequence`` and ``threshold`` as :meth:`rhythmic_jax.RhythmicMap.predict`
    takes them (:func:`rhythmic_jax.app.jobs.query_results`: ``top``)."""

    map: str = option("map folder", positional=True, path="reads")
    source: str = option(
        "query descriptors .npy, image folder or image", positional=True, path="frames"
    )
    decode: str | None = option(
        "how a query's place is read from the map's scores: hard (the best phase of "
        "each period, joined by the Chinese remainder; -1, no match, when they name "
        "no place of the route), soft (the place of the highest summed phase "
        "scores), topm (soft among the top best phases of each period)",
        choices=DECODERS,
        show_default="the map's own, hard for fit's",
    )
    sequence: int | None = option(
        "sequence length L (at most the number of queries)",
        domain=int_option(1),
        show_default="off, single frames",
    )
    threshold: float | None = option(
        "reject queries whose confidence is below this",
        domain=number_option(),
        show_default="none, every query gets a place",
    )
    out: str | None = option(
        "write predictions to this .npy", path="writes", output="file"
    )
    top: int = option(
        "best places listed per query (--json, --csv)", 5, domain=int_option(1)
    )
    csv: str | None = option(
        "write the results per query as CSV (query, place, place_name, score, "
        "confidence, top1, top1_name, top1_score, ...)",
        path="writes",
        output="file",
    )
    json: bool = option(
        "print JSON: the predictions, and per query its name (file name, else "
        "row number, as a string) and index (row), the place chosen (and its name "
        "where the map's reference names it), its score and confidence, and the "
        "--top best places with their scores",
        False,
    )
    pairs: str | None = option(
        "write hloc's retrieval pairs: 'query_name reference_name' per line, the "
        "--top best places of each query in rank order (as hloc's "
        "pairs_from_retrieval writes them), for hloc's local matching; the queries "
        "and places must have names (image folders, hloc .h5, or described .npy)",
        path="writes",
        output="file",
    )
    ground_truth: tuple[str, ...] | None = option(
        "with --csv or --json: add whether each answer is right ('correct'), "
        "the ground truth read as evaluate reads it",
        nargs="+",
        metavar="FILE",
        path="reads",
    )
    ground_truth_format: str | None = option(
        "the --ground-truth file's format",
        choices=GROUND_TRUTH_FORMATS,
        show_default="read from what it holds",
    )
    tolerance_m: float = option(
        "radius of a right match for positions, metres", 25.0, domain=number_option(0)
    )
    reading: Reading = part(Reading, helps={"select": SELECT})

    RULES = (
        *READS,
        *SELECTS,
        Rule(("top",), "needs {opt:json}, {opt:csv} or {opt:pairs} (the results "
             "per query it sizes)",
             lambda j: j.json or j.csv is not None or j.pairs is not None),
        Rule(("ground_truth",), "needs {opt:json} or {opt:csv} (it adds their "
             "'correct')", lambda j: j.json or j.csv is not None),
        Rule(("ground_truth_format",), "needs {opt:ground_truth} (it names that "
             "file's format)", lambda j: j.ground_truth is not None),
        Rule(("tolerance_m",), "needs {opt:ground_truth} (positions or names: it "
             "is their radius of a right match)", lambda j: j.ground_truth is not None),
        *IGNORED,
    )  # fmt: skip


@dataclass(frozen=True)
class EvaluateJob(Job):
    """The map at ``map`` judged on the queries of ``source``, beside brute force,
    a baseline at the map's own bytes (int8 per place, else PCA) and, for an
    embedded map, brute force on its embedding, all over the reference frames
    (:func:`rhythmic_jax.app.jobs.evaluate`); ``ground_truth`` as
    :func:`rhythmic_jax.eval.ground_truth_files.load_ground_truth` reads it."""

    map: str = like(QueryJob, "map")
    source: str = like(QueryJob, "source")
    reference: str | None = option(
        "reference source for the brute-force line and the baselines at the "
        "map's bytes",
        path="frames",
        show_default="the sources the map was fitted on, when they are still there",
    )
    tolerance: int = option("frame tolerance", 0, domain=int_option(0))
    decode: str | None = like(QueryJob, "decode")
    sequence: int | None = option(
        "sequence length L, at most the number of queries (accuracy, PR and "
        "recall@K use the sequence scores)",
        domain=int_option(1),
        show_default="off",
    )
    ground_truth: tuple[str, ...] | None = option(
        "VPR-Bench ground_truth_new.npy; or QUERY_POSITIONS (the map's from fit "
        "--positions); or REF_POSITIONS QUERY_POSITIONS; or 'names' "
        "(@easting@northing@ file names)",
        nargs="+",
        metavar="FILE",
        path="reads",
        show_default="query i is place i",
    )
    ground_truth_format: str | None = option(
        "the --ground-truth file's format",
        choices=GROUND_TRUTH_FORMATS,
        show_default="read from what it holds; its name only breaks a tie",
    )
    tolerance_m: float = like(QueryJob, "tolerance_m")
    recall_over: str = option(
        "recall@K's denominator: the queries with a right place (matched, "
        "VPR_Tutorial's) or every query (all, VPR-methods-evaluation's); the table "
        "says which",
        "matched",
        choices=RECALL_OVER,
    )
    plot: str | None = option(
        "write PR curves, recall@N (N = 1..20) and the predicted place against "
        "query index along the route (.png)",
        path="writes",
        output="made",
        suffix=(".png",),
    )
    matches: str | None = option(
        "draw queries beside the place chosen and the right place, 4 successes and "
        "the 4 most confident failures (.png; the queries and the reference as "
        "image folders, or descriptor files describe wrote, which name their "
        "frames)",
        path="writes",
        output="made",
        suffix=(".png",),
    )
    reference_images: str | None = option(
        "with --matches: the reference frames' image folder",
        path="reads",
        show_default="the map's reference, or the folder its descriptor file's "
        "record names",
    )
    query_images: str | None = option(
        "with --matches: the query frames' image folder",
        path="reads",
        show_default="the queries, or the folder their descriptor file's record names",
    )
    per_query: str | None = option(
        "write each query's result (.csv or .json by the suffix): its name and "
        "index, the place chosen and its name, the right places, correct or not, "
        "score, confidence and its --num-preds best places",
        path="writes",
        output="made",
        suffix=(".csv", ".json"),
    )
    num_preds: int = option(
        "best places kept per query in --per-query", 5, domain=int_option(1)
    )
    recall_values: str = option(
        "the K of recall@K, comma-separated", "1,5,10,20", metavar="K,K,..."
    )
    json: bool = option("print JSON", False)
    reading: Reading = part(Reading, helps={
        "select": SELECT + " (an .h5 reference: the map's prefix)"})  # fmt: skip

    RULES = (
        *READS,
        *SELECTS,
        Rule(("tolerance",), "acts only without {opt:ground_truth} (which names the "
             "right places itself)", lambda j: j.ground_truth is None),
        Rule(("tolerance_m",), "needs {opt:ground_truth} (positions or names: it is "
             "their radius of a right match)", lambda j: j.ground_truth is not None),
        Rule(("ground_truth_format",), "needs {opt:ground_truth} (it names that "
             "file's format)", lambda j: j.ground_truth is not None),
        Rule(("reference_images", "query_images"), "needs {opt:matches} (it names "
             "the frames drawn)", lambda j: j.matches is not None),
        Rule(("num_preds",), "needs {opt:per_query} (the records it sizes)",
             lambda j: j.per_query is not None),
        Rule(("recall_values",), "must be integers >= 1, comma-separated (1,5,10)",
             lambda j: recall_values(j.recall_values) is not None),
        *IGNORED,
    )  # fmt: skip


@dataclass(frozen=True)
class FrontierJob(Job):
    """Every representation of ``reference``'s places judged on ``queries``
    (:func:`rhythmic_jax.app.frontier.frontier`): maps as (r, level), ITQ bits
    and PQ sub-quantisers of ``grid`` (:data:`GRIDS`) unless ``maps``, ``bits``
    or ``pq`` say otherwise, at every sequence length of ``lengths``."""

    reference: str = option(
        "reference descriptors (.npy, .h5) or folder", positional=True, path="reads"
    )
    queries: str = option(
        "query descriptors (.npy, .h5) or folder", positional=True, path="reads"
    )
    select: tuple[str, str] | None = option(
        "the images of hloc .h5 files whose names start with REF_PREFIX, "
        "QUERY_PREFIX ('' takes all): one file split in two",
        nargs=2,
        metavar=("REF_PREFIX", "QUERY_PREFIX"),
    )
    ground_truth: tuple[str, ...] | None = like(
        EvaluateJob, "ground_truth", "as evaluate reads it"
    )
    ground_truth_format: str | None = like(EvaluateJob, "ground_truth_format")
    recall_over: str = like(EvaluateJob, "recall_over")
    tolerance: int = like(EvaluateJob, "tolerance")
    tolerance_m: float = like(EvaluateJob, "tolerance_m", "radius for positions, m")
    budget: float | None = option(
        "name the best representation within this many bytes",
        metavar="BYTES_PER_PLACE",
        domain=number_option(0),
    )
    grid: str = option(
        "the representations fitted unless --maps, --bits or --pq say otherwise: "
        f"small ({grid_text('small')}: a couple of minutes on a few thousand "
        f"places), full ({grid_text('full')})",
        "small",
        choices=tuple(GRIDS),
    )
    maps: str | None = option(
        "maps as r:level,...", domain=pair_list(), show_default="the --grid's"
    )
    bits: str | None = option(
        "ITQ code sizes, comma-separated",
        domain=int_list(1),
        show_default="the --grid's",
    )
    pq: str | None = option(
        "PQ sub-quantisers ('': none)",
        domain=int_list(1, empty=True),
        show_default="the --grid's",
    )
    lengths: str = option(
        "sequence lengths L, each at most the queries", "1,5,10", domain=int_list(1)
    )
    descriptor: str | None = option(
        "descriptor for image folders", show_default="patchnorm"
    )
    input_size: str | None = like(Reading, "input_size")
    recall_values: str = like(
        EvaluateJob,
        "recall_values",
        "the K of each row's single-frame recall@K "
        "(rows, --json, --csv: recall@K L=1), comma-separated; given, the table "
        "shows them too",
    )
    cache: str = option("folder keeping fitted maps and codes", "", show_default="none")
    csv: str | None = option("write the rows as CSV", path="writes", output="file")
    plot: str | None = option(
        "draw the frontier (.png)", path="writes", output="file", suffix=(".png",)
    )
    json: bool = like(EvaluateJob, "json")

    RULES = (
        Rule(("input_size",), READS[2].says, lambda j: size_ok(j.input_size)),
        Rule(("recall_values",), next(r.says for r in EvaluateJob.RULES
                                      if r.options == ("recall_values",)),
             lambda j: recall_values(j.recall_values) is not None),
        Rule(("ground_truth_format",), "needs {opt:ground_truth}",
             lambda j: j.ground_truth is not None),
    )  # fmt: skip
