"""What the fleet's two query scripts share: their arguments, and how they print rows.

Imported by `duckdb_verdicts.py` and `spark_verdicts.py` (beside them, so found as they run).
"""

import argparse
import datetime
import json
import pathlib
import signal

# Piped into `head`: end quietly, as a command-line tool does.
signal.signal(signal.SIGPIPE, signal.SIG_DFL)

REPO = pathlib.Path(__file__).resolve().parents[2]


def arguments(doc, runs):
    """The command line both scripts take; `runs`, the default number of times a query runs."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("fleet", help="the export's folder (with flights/ and samples/)")
    parser.add_argument(
        "--sql",
        action="append",
        help="an SQL file (more than once: each in turn); default docs/fleet/verdicts.sql",
    )
    parser.add_argument("--json", action="store_true", help="one JSON object per row")
    parser.add_argument(
        "--runs", type=int, default=runs, help=f"times each query runs (default {runs})"
    )
    parser.add_argument(
        "--timing",
        action="store_true",
        help="print, per SQL file, its last run's seconds and its rows, not the rows",
    )
    return parser


def sql_files(args):
    """The SQL files asked for, as (path, text)."""
    paths = args.sql or [str(REPO / "docs/fleet/verdicts.sql")]
    return [(path, pathlib.Path(path).read_text()) for path in paths]


def plain(value):
    """A value as JSON takes it: timestamps and dates as ISO 8601 text."""
    if isinstance(value, (datetime.datetime, datetime.date)):
        return value.isoformat()
    return value


def print_rows(names, rows, as_json):
    """Rows (sequences in the order of `names`) as a table, or as one JSON object a line."""
    if as_json:
        for row in rows:
            print(json.dumps({n: plain(v) for n, v in zip(names, row)}))
        return
    shown = [[("" if v is None else str(plain(v))) for v in row] for row in rows]
    widths = [max([len(n)] + [len(r[k]) for r in shown]) for k, n in enumerate(names)]
    print("  ".join(n.ljust(w) for n, w in zip(names, widths)))
    for r in shown:
        print("  ".join(v.ljust(w) for v, w in zip(r, widths)))
