"""A starting point for analysing a gfcal run with Polars.

Loads DIR/trials and DIR/parameters as two tables, reproduces the per-parameter summary
(bias, RMSE, Cramer-Rao sigma, their ratio, 95% coverage) and checks it against DIR/summary.csv,
then plots the median and 5-95% band of each compensation's velocity error against horizon,
log-log, with a t^3 guide line.

    python examples/analysis.py results/quickstart [drift.png]
"""

import re
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import polars as pl  # noqa: E402

run = Path(sys.argv[1])
figure = Path(sys.argv[2]) if len(sys.argv) > 2 else run / "velocity_drift.png"

trials = pl.scan_parquet(run / "trials" / "**" / "*.parquet")
params = pl.scan_parquet(run / "parameters" / "**" / "*.parquet")

# The summary table: one row per cell and parameter (SI units, see the `unit` column).
summary = (
    params.filter(pl.col("error").is_not_nan())
    .group_by(["cell", "name", "unit"])
    .agg(
        n=pl.len(),
        bias=pl.col("error").mean(),
        rmse=(pl.col("error") ** 2).mean().sqrt(),
        crb_sigma=(pl.col("crb_sigma") ** 2).mean().sqrt(),
        coverage_95=(pl.col("error").abs() <= 1.96 * pl.col("estimated_sigma")).mean(),
        # RMS of the normalised error: ~1 for an efficient estimator even when the bound varies.
        ratio=((pl.col("error") / pl.col("crb_sigma")) ** 2).mean().sqrt(),
    )
    .sort(["cell", "name"])
    .collect()
)
with pl.Config(tbl_rows=12, tbl_cols=9):
    print(summary.head(12))

# The same numbers as gfcal's own summary.
ref = pl.read_csv(run / "summary.csv").filter(pl.col("table") == "parameter")
joined = summary.join(
    ref.select(["cell", "name", pl.col("rmse").alias("rmse_gfcal"), pl.col("ratio").alias("ratio_gfcal")]), on=["cell", "name"]
)
worst = max(
    ((joined["rmse"] - joined["rmse_gfcal"]).abs() / joined["rmse_gfcal"]).max(),
    ((joined["ratio"] - joined["ratio_gfcal"]).abs() / joined["ratio_gfcal"]).max(),
)
assert joined.height == summary.height and worst < 1e-9, f"summary differs from summary.csv by {worst}"
print(f"summary matches summary.csv for {joined.height} rows (largest relative difference {worst:.1e})")

# Velocity error against horizon, per compensation.
pattern = re.compile(r"^(nominal|estimated|true)_velocity_err_m_s_at_([0-9.]+)s$")
columns = [c for c in trials.collect_schema().names() if pattern.match(c)]
if not columns:
    sys.exit("no velocity drift columns in this run")
drift = trials.select(columns).collect()
fig, ax = plt.subplots(figsize=(6, 4.5))
for comp in ["nominal", "estimated", "true"]:
    cols = sorted((float(pattern.match(c).group(2)), c) for c in columns if c.startswith(comp + "_"))
    if not cols:
        continue
    horizons = [h for h, _ in cols]
    # Diverged navigations (+inf) count as larger than any value, as in summary.csv; "no estimate"
    # is null, which quantiles skip (runs written before issue 30 have NaN there: dropped too).
    q = [drift[c].drop_nulls().filter(drift[c].drop_nulls().is_not_nan()).quantile for _, c in cols]
    med = [f(0.5) for f in q]
    lo, hi = [f(0.05) for f in q], [f(0.95) for f in q]
    line = ax.loglog(horizons, med, marker="o", label=f"{comp}: median")[0]
    ax.fill_between(horizons, lo, hi, alpha=0.2, color=line.get_color(), label=f"{comp}: 5-95%")
    if comp == "nominal":
        ax.loglog(horizons, [med[0] * (h / horizons[0]) ** 3 for h in horizons], "k--", lw=0.8, label="t^3")
ax.set_xlabel("horizon (s)")
ax.set_ylabel("velocity error (m/s)")
ax.set_title(f"{run.name}: velocity drift, {drift.height} trials")
ax.legend(fontsize=8)
fig.tight_layout()
fig.savefig(figure, dpi=120)
print(f"wrote {figure}")
