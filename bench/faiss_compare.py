#!/usr/bin/env python3
"""Compare texsyn's exact masked-L1 search with faiss IndexFlat(METRIC_L1).

Generates seeded random u8 vectors and queries (all components defined), runs
`texsyn-bench kernel` on them as raw files, searches the same data with faiss
on float32 copies (k=1), checks that both give the same best distance for every
query (indices may differ only on exact ties), and prints seconds per batch,
queries/s and effective GB/s (N x D bytes x Q / time) for both.

    python3 bench/faiss_compare.py [--vectors 240000 --dims 192 --queries 64
                                    --threads 2 --min-time 1 --json]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

try:
    import numpy as np
    import faiss
except ImportError as e:  # pragma: no cover - depends on the environment
    print(
        f"faiss_compare: {e}.\n"
        "This script needs numpy and faiss (CPU build). Install them with:\n"
        "    pip install faiss-cpu numpy",
        file=sys.stderr,
    )
    sys.exit(2)

REPO_ROOT = Path(__file__).resolve().parent.parent
DEFAULT_BENCH = REPO_ROOT / "target" / "release" / "texsyn-bench"


def parse_args() -> argparse.Namespace:
    p = argparse.ArgumentParser(
        description="texsyn vs faiss IndexFlat(METRIC_L1): exact best-1 search throughput"
    )
    p.add_argument("--vectors", type=int, default=240_000, help="reference vectors N")
    p.add_argument("--dims", type=int, default=192, help="components per vector D")
    p.add_argument("--queries", type=int, default=64, help="queries per batch Q")
    p.add_argument("--threads", type=int, default=2, help="threads for both engines")
    p.add_argument("--seed", type=int, default=1, help="numpy RNG seed")
    p.add_argument(
        "--min-time",
        type=float,
        default=1.0,
        help="minimum seconds per measurement, best of >= 2 reps (same policy as texsyn)",
    )
    p.add_argument(
        "--kernel", default="auto", help="texsyn kernel: auto, scalar, avx2, avx512"
    )
    p.add_argument(
        "--texsyn-bench",
        type=Path,
        default=None,
        help=f"texsyn-bench binary (default: {DEFAULT_BENCH.relative_to(REPO_ROOT)} "
        "under the repo root, built with cargo if missing)",
    )
    p.add_argument("--json", action="store_true", help="print machine-readable results")
    a = p.parse_args()
    for name in ("vectors", "dims", "queries", "threads"):
        if getattr(a, name) < 1:
            p.error(f"--{name} must be >= 1")
    if a.min_time < 0:
        p.error("--min-time must be >= 0")
    return a


def bench_binary(path: Path | None) -> Path:
    if path is not None:
        if not path.is_file():
            sys.exit(f"faiss_compare: texsyn-bench binary {path} not found")
        return path
    if not DEFAULT_BENCH.is_file():
        print(
            "faiss_compare: building texsyn-bench (cargo build --release -p texsyn-bench)",
            file=sys.stderr,
        )
        subprocess.run(
            ["cargo", "build", "--release", "-p", "texsyn-bench"],
            cwd=REPO_ROOT,
            check=True,
        )
        if not DEFAULT_BENCH.is_file():
            sys.exit(f"faiss_compare: cargo did not produce {DEFAULT_BENCH}")
    return DEFAULT_BENCH


def run_texsyn(binary: Path, a: argparse.Namespace, vfile: Path, qfile: Path, afile: Path):
    cmd = [
        str(binary),
        "kernel",
        "--vectors", str(a.vectors),
        "--dims", str(a.dims),
        "--queries", str(a.queries),
        "--threads", str(a.threads),
        "--kernel", a.kernel,
        "--min-time", str(a.min_time),
        "--vectors-file", str(vfile),
        "--queries-file", str(qfile),
        "--answers-file", str(afile),
        "--json",
    ]  # fmt: skip
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode != 0:
        sys.exit(
            f"faiss_compare: {' '.join(cmd)} failed ({r.returncode}):\n{r.stderr.strip()}"
        )
    report = json.loads(r.stdout)
    rows = [line.split() for line in afile.read_text().splitlines() if line.strip()]
    if len(rows) != a.queries:
        sys.exit(f"faiss_compare: expected {a.queries} answers, got {len(rows)}")
    idx = np.array([int(x[0]) for x in rows], dtype=np.int64)
    dist = np.array([int(x[1]) for x in rows], dtype=np.int64)
    return report, idx, dist, cmd


def time_best(min_time: float, f):
    """Best wall time of f() over >= 2 repetitions and >= min_time seconds."""
    start = time.perf_counter()
    best, reps, out = float("inf"), 0, None
    while reps < 2 or time.perf_counter() - start < min_time:
        t = time.perf_counter()
        out = f()
        best = min(best, time.perf_counter() - t)
        reps += 1
    return best, reps, out


def l1(xb: np.ndarray, i: int, q: np.ndarray) -> int:
    return int(np.abs(xb[i].astype(np.int64) - q.astype(np.int64)).sum())


def main() -> int:
    a = parse_args()
    n, d, nq = a.vectors, a.dims, a.queries
    binary = bench_binary(a.texsyn_bench)

    rng = np.random.default_rng(a.seed)
    xb = rng.integers(0, 256, size=(n, d), dtype=np.uint8)
    xq = rng.integers(0, 256, size=(nq, d), dtype=np.uint8)

    with tempfile.TemporaryDirectory(prefix="texsyn-faiss-") as tmp:
        tmp = Path(tmp)
        vfile, qfile, afile = tmp / "vectors.u8", tmp / "queries.u8", tmp / "answers.txt"
        xb.tofile(vfile)
        xq.tofile(qfile)
        report, t_idx, t_dist, cmd = run_texsyn(binary, a, vfile, qfile, afile)

    # faiss on float32 copies; integer L1 sums stay far below 2^24, so exact.
    faiss.omp_set_num_threads(a.threads)
    index = faiss.IndexFlat(d, faiss.METRIC_L1)
    index.add(xb.astype(np.float32))
    xq_f = np.ascontiguousarray(xq.astype(np.float32))
    f_secs, f_reps, (f_dist_f, f_idx) = time_best(a.min_time, lambda: index.search(xq_f, 1))
    f_dist = f_dist_f[:, 0].astype(np.int64)
    f_idx = f_idx[:, 0].astype(np.int64)
    del index

    # Check: same best distance for every query; differing indices must be ties
    # (texsyn's index really has that distance, and faiss found no lower index
    # with it, since texsyn breaks ties to the lowest index).
    problems, ties = [], []
    for q in range(nq):
        td, fd, ti, fi = int(t_dist[q]), int(f_dist[q]), int(t_idx[q]), int(f_idx[q])
        if not (0 <= ti < n):
            problems.append(f"query {q}: texsyn index {ti} out of range")
            continue
        actual = l1(xb, ti, xq[q])
        if actual != td:
            problems.append(f"query {q}: texsyn reports dist {td} for index {ti}, actual {actual}")
        if td != fd:
            problems.append(f"query {q}: texsyn dist {td} (index {ti}) != faiss dist {fd} (index {fi})")
        elif ti != fi:
            if not (0 <= fi < n) or l1(xb, fi, xq[q]) != fd:
                problems.append(f"query {q}: faiss index {fi} does not have its distance {fd}")
            elif fi < ti:
                problems.append(
                    f"query {q}: tie at dist {td}, faiss found lower index {fi} < texsyn {ti}"
                )
            else:
                ties.append({"query": q, "dist": td, "texsyn": ti, "faiss": fi})

    bytes_per_batch = n * d * nq
    t_secs = float(report["batched"]["seconds"])

    def fig(secs: float) -> dict:
        return {
            "seconds_per_batch": secs,
            "queries_per_s": nq / secs,
            "effective_gb_per_s": bytes_per_batch / secs / 1e9,
        }

    results = {
        "vectors": n,
        "dims": d,
        "queries": nq,
        "threads": a.threads,
        "seed": a.seed,
        "min_time": a.min_time,
        "texsyn": {**fig(t_secs), "kernel": report["kernel"], "report": report},
        "faiss": {
            **fig(f_secs),
            "version": faiss.__version__,
            "omp_threads": faiss.omp_get_max_threads(),
            "repetitions": f_reps,
        },
        "ratio_queries_per_s": f_secs / t_secs,
        "check": {
            "ok": not problems,
            "distances_equal": bool(np.array_equal(t_dist, f_dist)),
            "index_ties": ties,
            "problems": problems,
        },
        "texsyn_command": cmd,
    }

    if a.json:
        print(json.dumps(results, indent=2))
    else:
        print(
            f"{n} vectors x {d} dims (u8), {nq} queries, k=1, L1, {a.threads} thread(s); "
            f"texsyn kernel {report['kernel']}, faiss {faiss.__version__} IndexFlat(METRIC_L1, float32)"
        )
        print(f"{'engine':<8} {'s/batch':>10} {'queries/s':>11} {'eff. GB/s':>10}")
        for name in ("texsyn", "faiss"):
            r = results[name]
            print(
                f"{name:<8} {r['seconds_per_batch']:>10.4f} {r['queries_per_s']:>11.1f} "
                f"{r['effective_gb_per_s']:>10.2f}"
            )
        print(f"texsyn/faiss (queries/s): {results['ratio_queries_per_s']:.2f}x")
        if problems:
            print(f"CHECK FAILED: {len(problems)} problem(s)")
            for p in problems:
                print(f"  {p}")
        else:
            tie_note = f", {len(ties)} index tie(s) verified" if ties else ", identical indices"
            print(f"check: all {nq} distances equal{tie_note}")
    return 0 if not problems else 1


if __name__ == "__main__":
    sys.exit(main())
