"""Reads a gfcal run folder with polars and with pyarrow and checks it against its run.json:
row counts, columns, units. Usage: python check_parquet.py DIR"""

import json
import re
import sys
from pathlib import Path

import polars as pl
import pyarrow.dataset as ds

UNIT_OF_SUFFIX = {"_rad_s": "rad/s", "_rad": "rad", "_m_s": "m/s", "_m": "m"}


def fail(msg):
    print(f"check_parquet: FAILED: {msg}")
    sys.exit(1)


def main(run_dir):
    run_dir = Path(run_dir)
    run = json.loads((run_dir / "run.json").read_text())
    total = run["trials_total"]
    if run.get("finished") is None:
        fail("run.json says the run is not finished")

    trials = pl.scan_parquet(str(run_dir / "trials" / "**" / "*.parquet")).collect()
    params = pl.scan_parquet(str(run_dir / "parameters" / "**" / "*.parquet")).collect()
    if trials.height != total:
        fail(f"polars reads {trials.height} trials, run.json says {total}")
    if sorted(trials["trial_id"].to_list()) != list(range(total)):
        fail("trial ids are not 0..N-1, each once")
    n_accel = params["accelerometer"].max()
    if params.height != total * 7 * n_accel:
        fail(f"polars reads {params.height} parameter rows, expected {total} x 7 x {n_accel}")
    for col in ["trial_id", "cell", "converged", "iterations", "cost", "condition_number", "message",
                "white_noise_density_m_s2_per_sqrt_hz", "seed", "stream"] + run["factor_keys"]:
        if col not in trials.columns:
            fail(f"trials has no column {col}")
    for col in ["trial_id", "accelerometer", "name", "unit", "true", "estimated", "error", "crb_sigma"]:
        if col not in params.columns:
            fail(f"parameters has no column {col}")
    if not (params["error"].drop_nans() - (params["estimated"] - params["true"]).drop_nans()).abs().max() < 1e-12:
        fail("error != estimated - true")

    # pyarrow: the same rows, and each column's unit in the schema.
    dataset = ds.dataset(str(run_dir / "trials"), format="parquet")
    if dataset.count_rows() != total:
        fail(f"pyarrow reads {dataset.count_rows()} trials")
    if ds.dataset(str(run_dir / "parameters"), format="parquet").count_rows() != params.height:
        fail("pyarrow and polars disagree on parameters")
    drift_cols = [f for f in dataset.schema if re.search(r"_err_.*_at_[0-9.]+s$", f.name)]
    if not drift_cols:
        fail("no drift columns")
    for field in dataset.schema:
        meta = field.metadata or {}
        if b"unit" not in meta:
            fail(f"column {field.name} has no unit in the schema")
    for field in drift_cols:
        # "No estimate" is null (skipped by quantiles), never NaN (issue 30).
        if trials[field.name].is_nan().sum() > 0:
            fail(f"{field.name}: NaN where there is no estimate (it must be null)")
        unit = field.metadata[b"unit"].decode()
        stem = field.name.split("_at_")[0]
        expected = next(u for s, u in sorted(UNIT_OF_SUFFIX.items(), key=lambda kv: -len(kv[0])) if stem.endswith(s))
        if unit != expected:
            fail(f"{field.name}: unit {unit}, expected {expected}")
    meta = dataset.schema.metadata or {}
    file_meta = ds.dataset(str(run_dir / "trials"), format="parquet").files[0]
    import pyarrow.parquet as pq
    kv = pq.read_metadata(file_meta).metadata
    if kv.get(b"gfcal:seed", b"").decode() != str(run["seed"]):
        fail("the seed in the Parquet metadata differs from run.json")
    if kv.get(b"gfcal:config", b"").decode() != run["config_text"]:
        fail("the config in the Parquet metadata differs from run.json")
    schema_meta = pq.read_table(file_meta).schema.metadata or {}
    if schema_meta.get(b"gfcal:seed", b"").decode() != str(run["seed"]):
        fail("the Arrow schema's metadata (read_table(f).schema.metadata) has no gfcal:seed")
    summary = pl.read_csv(run_dir / "summary.csv")
    if summary.filter(pl.col("table") == "parameter").height == 0:
        fail("summary.csv has no parameter rows")
    # The fits rows: per cell, the outcomes add up to the cell's trials, and `estimated` are the converged.
    fits = summary.filter(pl.col("table") == "fits").group_by("cell").agg(pl.col("n").sum()).sort("cell")
    per_cell = trials.group_by("cell").agg(n=pl.len(), converged=pl.col("converged").sum()).sort("cell")
    if fits["n"].to_list() != per_cell["n"].to_list():
        fail(f"summary.csv's fits rows count {fits['n'].to_list()} trials per cell, the table {per_cell['n'].to_list()}")
    estimated = summary.filter((pl.col("table") == "fits") & (pl.col("name") == "estimated"))
    if estimated["n"].sum() > per_cell["converged"].sum():
        fail("more `estimated` fits than converged trials")
    print(f"check_parquet: ok: {total} trials, {params.height} parameter rows, "
          f"{len(drift_cols)} drift columns with units; polars {pl.__version__}")


if __name__ == "__main__":
    main(sys.argv[1])
