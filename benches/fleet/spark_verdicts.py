#!/usr/bin/env python3
"""The same SQL as duckdb_verdicts.py, in Spark SQL (PySpark, local mode), over the same folder.

    python3 benches/fleet/spark_verdicts.py FLEET [--sql FILE] [--json] [--master local[2]]

For fleets that outgrow one machine: the SQL files of `docs/fleet/` run unchanged in Spark.
`FLEET/flights` and `FLEET/samples` (folders of Parquet files, as `lj9da-bridge record parquet`
writes them; Spark skips the hidden files of an export in progress) become the temporary
views `flights` and `samples`; the session's time zone is UTC. The one difference in how the
file is handed over: Spark's `sql()` takes one statement without the closing `;`, which is
cut off here.

Printed: a table (or JSON lines), then on stderr the times to start Spark, to register the
views and to run the query (collecting its rows to the driver), in seconds; the query is run
`--runs` times (default 3: the first pays for Spark's code generation and the Parquet footers).

Needs `pyspark` (`pip install pyspark`) and a Java runtime (Debian: `openjdk-17-jre-headless`).
"""

import argparse
import datetime
import json
import os
import pathlib
import sys
import time

REPO = pathlib.Path(__file__).resolve().parents[2]


def statement(sql):
    """The SQL file's one statement as Spark takes it: without the closing semicolon."""
    return sql.strip().rstrip(";").strip()


def plain(value):
    if isinstance(value, (datetime.datetime, datetime.date)):
        return value.isoformat()
    return value


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fleet", help="the export's folder (with flights/ and samples/)")
    parser.add_argument("--sql", default=str(REPO / "docs/fleet/verdicts.sql"))
    parser.add_argument("--json", action="store_true", help="one JSON object per row")
    parser.add_argument("--master", default="local[2]")
    parser.add_argument("--runs", type=int, default=3)
    args = parser.parse_args()
    sql = statement(pathlib.Path(args.sql).read_text())

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
    runs = []
    rows = []
    for _ in range(max(1, args.runs)):
        t0 = time.perf_counter()
        result = spark.sql(sql)
        rows = result.collect()
        runs.append(time.perf_counter() - t0)
    names = result.columns
    if args.json:
        for row in rows:
            print(json.dumps({n: plain(row[n]) for n in names}))
    else:
        shown = [[("" if row[n] is None else str(plain(row[n]))) for n in names] for row in rows]
        widths = [max([len(n)] + [len(r[k]) for r in shown]) for k, n in enumerate(names)]
        print("  ".join(n.ljust(w) for n, w in zip(names, widths)))
        for r in shown:
            print("  ".join(v.ljust(w) for v, w in zip(r, widths)))
    print(
        f"spark {spark.version} ({args.master}): {len(rows)} rows; start {started - began:.1f} s, "
        f"views {registered - started:.2f} s, query "
        + ", ".join(f"{t:.2f}" for t in runs)
        + " s",
        file=sys.stderr,
    )
    spark.stop()


if __name__ == "__main__":
    main()
