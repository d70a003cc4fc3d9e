"""bench_fit's GTR campaign (seed 0, 1188 rows) as a measurement table at /tmp/jk-pool/t.csv, for cli.sh."""
import os
import sys

sys.path.insert(0, os.getcwd())
import jax  # noqa: E402

jax.config.update("jax_enable_x64", True)
from benchmarks.bench_fit import _lobe_campaign  # noqa: E402
from jkatana.measure.table import MeasurementTable, write_table  # noqa: E402

d = _lobe_campaign("gtr")
os.makedirs("/tmp/jk-pool", exist_ok=True)
write_table(MeasurementTable.from_columns(capture=[f"c{i}" for i in range(d.value.size)],
                                          region=["hiraji"] * d.value.size, theta_i_deg=d.theta_i_deg,
                                          theta_r_deg=d.theta_r_deg, value=d.value, sigma=d.sigma),
            "/tmp/jk-pool/t.csv")
