#!/usr/bin/env python3
"""A fleet's wear verdicts, and an ad-hoc question, in DuckDB over a folder of Parquet exports.

    python3 benches/fleet/duckdb_verdicts.py FLEET [--sql FILE] [--json]

FLEET is a folder made by `lj9da-bridge record parquet … --out FLEET` (one or many runs of it,
for one aircraft or many): its `flights/*.parquet` become the view `flights`, its
`samples/*.parquet` the view `samples`, and the SQL file (default `docs/fleet/verdicts.sql`
beside this script's repository; `docs/fleet/adhoc.sql` for the ad-hoc question) is run as it
is. The session's time zone is UTC. Printed: a table (or, with `--json`, one JSON object per
row), then on stderr the rows and the query's wall time.

Needs the `duckdb` Python package (`pip install duckdb`).
"""

import argparse
import datetime
import json
import pathlib
import sys
import time

import duckdb

REPO = pathlib.Path(__file__).resolve().parents[2]


def quoted(path):
    """A path as an SQL string literal."""
    return "'" + str(path).replace("'", "''") + "'"


def quoted_name(name):
    """A column name as an SQL identifier."""
    return '"' + name.replace('"', '""') + '"'


def connect(fleet):
    """A DuckDB connection with the views `flights` and `samples` over the folder `fleet`."""
    con = duckdb.connect()
    con.execute("SET TimeZone = 'UTC'")
    # A long query draws a progress bar on stdout, among the rows.
    con.execute("SET enable_progress_bar = false")
    fleet = pathlib.Path(fleet)
    for view in ("flights", "samples"):
        files = fleet / view / "*.parquet"
        con.execute(f"CREATE VIEW {view} AS SELECT * FROM read_parquet({quoted(files)})")
    return con


def plain(value):
    """A value as JSON takes it: timestamps as ISO 8601 text."""
    if isinstance(value, (datetime.datetime, datetime.date)):
        return value.isoformat()
    return value


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("fleet", help="the export's folder (with flights/ and samples/)")
    parser.add_argument("--sql", default=str(REPO / "docs/fleet/verdicts.sql"))
    parser.add_argument("--json", action="store_true", help="one JSON object per row")
    args = parser.parse_args()
    sql = pathlib.Path(args.sql).read_text()
    con = connect(args.fleet)
    began = time.perf_counter()
    relation = con.sql(sql)
    # A timestamp with a time zone becomes text (UTC, the session's zone) in DuckDB itself: it
    # prints the same for every client (DuckDB clients before 1.x needed pytz for it).
    names = relation.columns
    relation = relation.project(
        ", ".join(
            f"CAST({quoted_name(n)} AS VARCHAR) AS {quoted_name(n)}"
            if "TIME ZONE" in str(t).upper()
            else quoted_name(n)
            for n, t in zip(names, relation.types)
        )
    )
    rows = relation.fetchall()
    took = time.perf_counter() - began
    if args.json:
        for row in rows:
            print(json.dumps({n: plain(v) for n, v in zip(names, row)}))
    else:
        shown = [[("" if v is None else str(plain(v))) for v in row] for row in rows]
        widths = [max([len(n)] + [len(r[k]) for r in shown]) for k, n in enumerate(names)]
        print("  ".join(n.ljust(w) for n, w in zip(names, widths)))
        for r in shown:
            print("  ".join(v.ljust(w) for v, w in zip(r, widths)))
    print(f"duckdb {duckdb.__version__}: {len(rows)} rows in {took:.3f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
