#!/usr/bin/env python3
"""A fleet's wear verdicts, and an ad-hoc question, in DuckDB over a folder of Parquet exports.

    python3 benches/fleet/duckdb_verdicts.py FLEET [--sql FILE]… [--json] [--runs N] [--timing]

FLEET is a folder made by `lj9da-bridge record parquet … --out FLEET` (one or many runs of it,
for one aircraft or many): its `flights/*.parquet` become the view `flights`, its
`samples/*.parquet` the view `samples`, and the SQL file (default `docs/fleet/verdicts.sql`
beside this script's repository; `docs/fleet/adhoc.sql` for the ad-hoc question) is run as it
is. The session's time zone is UTC. Printed: a table (or, with `--json`, one JSON object per
row), then on stderr the rows and the query's wall time; with `--timing`, one line per SQL
file instead: the last run's seconds and the rows (the bench's figures: `--runs 2`, warm).

Needs the `duckdb` Python package (`pip install duckdb`).
"""

import pathlib
import sys
import time

import duckdb

from fleet_sql import arguments, print_rows, sql_files


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


def run(con, sql):
    """The query's column names and rows."""
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
    return names, relation.fetchall()


def main():
    args = arguments(__doc__, runs=1).parse_args()
    con = connect(args.fleet)
    for path, sql in sql_files(args):
        for _ in range(max(1, args.runs)):
            began = time.perf_counter()
            names, rows = run(con, sql)
            took = time.perf_counter() - began
        if args.timing:
            print(f"{took:.3f} {len(rows)}")
            continue
        print_rows(names, rows, args.json)
        print(
            f"duckdb {duckdb.__version__}: {path}: {len(rows)} rows in {took:.3f} s",
            file=sys.stderr,
        )


if __name__ == "__main__":
    main()
