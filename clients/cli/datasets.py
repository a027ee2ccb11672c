"""`fpscan datasets`: list and delete the datasets uploaded to a server
(``GET /api/datasets``, ``DELETE /api/datasets/{id}``).

Exit codes (``fpscan.clients.cli.common.client_errors``, as every client command): 0 done; 2 the
server refused the input (an unknown id: 404, a malformed id: 422), with its reason on
stderr; 1 any other failure, the server's state included (a dataset an active
reconstruction reads: 409; server unreachable, server error)."""
from __future__ import annotations

import argparse

from fpscan.clients.cli.common import add_server_options, client_errors, delete_each, format_bytes

__all__ = ["COMMAND", "HELP", "add_arguments", "run", "full_ids"]

COMMAND = "datasets"
HELP = "list or delete the datasets uploaded to the server (size on disk, content hash, jobs that read them)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser, changed in place.
    """
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    p = sub.add_parser("list", help="list the stored datasets",
                       description="List the stored datasets, oldest first: id, format, size on disk, "
                                   "upload time, name and the jobs that read them.")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--ids", action="store_true", help="print only the full dataset ids, one per line, oldest "
                   "first")
    add_server_options(p, required=True)
    p = sub.add_parser("delete", help="delete datasets and their files",
                       description="Delete stored datasets with their files; an id may be a unique prefix "
                                   "(as `fpscan datasets list` shows it), as job ids may. Refused for an "
                                   "unknown or ambiguous id (exit 2) or a dataset a queued, running or paused "
                                   "reconstruction reads (exit 1).")
    p.add_argument("dataset_ids", nargs="+", metavar="dataset_id")
    add_server_options(p, required=True)


@client_errors
def run(args: argparse.Namespace) -> int:
    """Run this sub-command with the parsed ``args``; return the exit status.

    Parameters
    ----------
    args : argparse.Namespace
        The parsed command line (:func:`add_arguments`).

    Returns
    -------
    int
        The exit status: 0 on success. Errors of the client become exit 1, or 2 when the server refused
        the request as given (``fpscan.clients.cli.common.client_errors``); other refused input and
        failures raise (:func:`fpscan.clients.cli.main` reports them and sets the status).
    """
    import json
    import time

    from fpscan.clients.cli.common import make_client
    from fpscan.clients.http import to_dict

    with make_client(args) as api:
        if args.action == "list":
            rows = api.list_datasets()
            if args.json:
                print(json.dumps([to_dict(d) for d in rows], indent=2))
                return 0
            if args.ids:
                print("\n".join(d["dataset_id"] for d in rows))
                return 0
            print(f"{'id':<12}  {'format':<10}  {'size':>10}  {'uploaded':<16}  {'jobs':>4}  name")
            for d in rows:
                when = time.strftime("%Y-%m-%d %H:%M", time.localtime(d.get("created") or 0))
                jobs = f"{len(d.get('jobs') or [])}{'*' if d.get('in_use') else ''}"
                print(f"{d['dataset_id']:<12.12}  {d.get('format') or '?':<10}  {format_bytes(d['size_bytes']):>10}  "
                      f"{when:<16}  {jobs:>4}  {d.get('name') or ''}".rstrip())
            total = sum(int(d["size_bytes"]) for d in rows)
            print(f"{len(rows)} dataset{'s' if len(rows) != 1 else ''}, {format_bytes(total)} on disk"
                  + (" (* = read by an active job)" if any(d.get("in_use") for d in rows) else ""))
            return 0
        full = full_ids(args.dataset_ids, [d["dataset_id"] for d in api.list_datasets()], "dataset")
        delete_each(full, api.delete_dataset)
        return 0


def full_ids(given: list[str], known: list[str], what: str) -> list[str]:
    """Each of ``given`` as the one id of ``known`` it is a prefix of (a full id stays as it
    is, known or not: the server answers for it). Raises UsageError (exit 2) for a prefix
    that matches several ids, naming them, or none.

    Parameters
    ----------
    given : list of str
        Ids or id prefixes from the command line.
    known : list of str
        The server's ids.
    what : str
        What they are, for messages (``"dataset"``).

    Returns
    -------
    list of str
        The full ids, in the order given.

    Raises
    ------
    UsageError
        A prefix that matches several ids (naming them), or none (unless 32 characters or
        longer: then it is passed on as a full id).
    """
    from fpscan.clients.cli.common import UsageError

    out = []
    for g in given:
        matches = [k for k in known if k.startswith(g)]
        if g in known or (not matches and len(g) >= 32):
            out.append(g)
        elif len(matches) == 1:
            out.append(matches[0])
        elif matches:
            raise UsageError(f"{what} id prefix {g!r} matches several {what}s ({', '.join(m[:12] for m in matches)}): "
                             "give more characters")
        else:
            raise UsageError(f"no {what} id starts with {g!r} (fpscan {what}s list shows them)")
    return out
