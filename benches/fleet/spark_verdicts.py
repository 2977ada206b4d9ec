#!/usr/bin/env python3
"""The same SQL as duckdb_verdicts.py, in Spark SQL (PySpark, local mode), over the same folder.

    python3 benches/fleet/spark_verdicts.py FLEET [--sql FILE]… [--json] [--runs N] [--timing]
                                            [--master local[2]]

For fleets that outgrow one machine: the SQL files of `docs/fleet/` run unchanged in Spark.
`FLEET/flights` and `FLEET/samples` (folders of Parquet files, as `lj9da-bridge record parquet`
writes them; Spark skips the hidden files of an export in progress) become the temporary
views `flights` and `samples`; the session's time zone is UTC. The one difference in how the
file is handed over: Spark's `sql()` takes one statement without the closing `;`, which is
cut off here.

Printed: a table (or JSON lines), then on stderr the times to start Spark, to register the
views and to run the query (collecting its rows to the driver), in seconds; the query is run
`--runs` times (default 3: the first pays for Spark's code generation and the Parquet footers).
With `--timing`, one line per SQL file instead: the last run's seconds and the rows.

Needs `pyspark` (`pip install pyspark`) and a Java runtime (Debian: `openjdk-17-jre-headless`).
"""

import os
import pathlib
import sys
import time

from fleet_sql import arguments, print_rows, sql_files


def statement(sql):
    """The SQL file's one statement as Spark takes it: without the closing semicolon."""
    return sql.strip().rstrip(";").strip()


def main():
    parser = arguments(__doc__, runs=3)
    parser.add_argument("--master", default="local[2]")
    args = parser.parse_args()

    # PySpark hands timestamps to Python in the process's local time zone: UTC, as the session.
    os.environ["TZ"] = "UTC"
    time.tzset()
    began = time.perf_counter()
    from pyspark.sql import SparkSession

    spark = (
        SparkSession.builder.master(args.master)
        .appName("lj9da-fleet")
        .config("spark.sql.session.timeZone", "UTC")
        .config("spark.ui.enabled", "false")
        .config("spark.sql.shuffle.partitions", "8")
        .getOrCreate()
    )
    spark.sparkContext.setLogLevel("ERROR")
    started = time.perf_counter()
    fleet = pathlib.Path(args.fleet)
    for view in ("flights", "samples"):
        spark.read.parquet(str(fleet / view)).createOrReplaceTempView(view)
    registered = time.perf_counter()
    for path, sql in sql_files(args):
        runs = []
        rows = []
        for _ in range(max(1, args.runs)):
            t0 = time.perf_counter()
            result = spark.sql(statement(sql))
            rows = result.collect()
            runs.append(time.perf_counter() - t0)
        if args.timing:
            print(f"{runs[-1]:.3f} {len(rows)}")
            continue
        names = result.columns
        print_rows(names, [[row[n] for n in names] for row in rows], args.json)
        print(
            f"spark {spark.version} ({args.master}): {path}: {len(rows)} rows; start "
            f"{started - began:.1f} s, views {registered - started:.2f} s, query "
            + ", ".join(f"{t:.2f}" for t in runs)
            + " s",
            file=sys.stderr,
        )
    spark.stop()


if __name__ == "__main__":
    main()
