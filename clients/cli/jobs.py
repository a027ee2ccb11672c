"""`fpscan jobs`: list, get, wait on, resume, cancel and delete the server's jobs (scans and
reconstructions) over HTTP (``GET /api/jobs``, ``GET /api/jobs/{id}``, the SSE stream,
``POST /api/scans/{id}/resume``, ``POST /api/jobs/{id}/cancel``, ``DELETE /api/jobs/{id}``)."""
from __future__ import annotations

import argparse
from typing import Any

from fpscan.clients.cli.common import (
    add_progress_option,
    add_server_options,
    client_errors,
    delete_each,
    seconds,
)

__all__ = ["COMMAND", "HELP", "STATES", "KINDS", "PAGE", "add_arguments", "run", "mask_words"]

COMMAND = "jobs"
HELP = "list, get, wait on, resume (a paused scan), cancel or delete the server's jobs (scans, reconstructions)"

STATES = ("queued", "running", "paused", "succeeded", "failed", "cancelled")
KINDS = ("scan", "recon")
#: jobs a page of ``fpscan jobs list`` asks for (the server's default and at most 1000)
PAGE = 200


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """Declare this sub-command's options on ``parser`` (an ``argparse`` sub-parser).

    Parameters
    ----------
    parser : argparse.ArgumentParser
        The sub-command's parser, changed in place.
    """
    sub = parser.add_subparsers(dest="action", metavar="ACTION")
    sub.required = True
    p = sub.add_parser("list", help="list jobs", description="List jobs, newest first.")
    p.add_argument("--state", choices=STATES, help="only jobs in this state")
    p.add_argument("--kind", choices=KINDS, help="only jobs of this kind")
    p.add_argument("--limit", type=int, default=PAGE, metavar="N",
                   help=f"the N newest (default {PAGE}; a note on stderr says when there are more)")
    p.add_argument("--all", action="store_true", help="every job, a page at a time")
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--ids", action="store_true", help="print only the full job ids, one per line, newest first "
                   "(for scripts: JOB=$(fpscan jobs list --kind recon --ids | head -1))")
    add_server_options(p, required=True)
    p = sub.add_parser("get", help="show one job as JSON", description="Show one job as JSON.")
    p.add_argument("job_id")
    add_server_options(p, required=True)
    p = sub.add_parser("wait", help="wait until a job ends, with a progress bar",
                       description="Wait until a job ends; exit 0 if it succeeded, 1 otherwise.")
    p.add_argument("job_id")
    p.add_argument("--timeout", type=seconds("--timeout"), default=None, metavar="S", help="give up after S seconds")
    add_progress_option(p)
    add_server_options(p, required=True)
    p = sub.add_parser("resume", help="resume a paused scan",
                       description="Resume a paused scan job (paused by `pause`, or by a restart of the server: "
                                   "FPSCAN_RESUME_SCANS) from its first missing point; follow it with "
                                   "`fpscan jobs wait ID`.")
    p.add_argument("job_id")
    add_server_options(p, required=True)
    p = sub.add_parser("cancel", help="cancel a job", description="Cancel a job (cooperative).")
    p.add_argument("job_id")
    add_server_options(p, required=True)
    p = sub.add_parser("delete", help="delete finished jobs and their files",
                       description="Delete finished jobs with their files (a scan's scan file, a "
                                   "reconstruction's volume and pictures). Refused (exit 1) for a job "
                                   "that is queued, running or paused, or whose scan an active "
                                   "reconstruction reads: cancel it first.")
    p.add_argument("job_ids", nargs="+", metavar="job_id")
    add_server_options(p, required=True)


def mask_words(mask: object) -> str:
    """What a reconstruction's input samples (its record's ``params["mask"]``): ``full 96×96``
    or ``equisteradian, 400 of 9216 points``; ``""`` for a record without it. The web page's jobs
    table says the same (clients/web/app.js: maskWords)."""
    if not isinstance(mask, dict) or not isinstance(mask.get("lattice"), list | tuple) or not mask["lattice"]:
        return ""
    n_x = int(mask["lattice"][0])
    n_y = int(mask["lattice"][1]) if len(mask["lattice"]) > 1 and mask["lattice"][1] else 1
    total = n_x * n_y
    if mask.get("n_points") == total:
        return f"full {n_x}×{n_y}" if n_y > 1 else f"full {n_x}"
    return f"{mask.get('kind') or 'points'}, {mask.get('n_points')} of {total} points"


def _listed(api: Any, args: argparse.Namespace) -> list:
    """The jobs ``jobs list`` prints: the ``--limit`` newest, or with ``--all`` every page
    (``GET /api/jobs?before=``); a note on stderr where more exist than it prints."""
    import sys

    from fpscan.clients.cli.common import UsageError
    from fpscan.clients.http import field_of

    if not 1 <= args.limit <= 1000:
        raise UsageError(f"--limit must be 1 to 1000, got {args.limit}")
    jobs: list = []
    seen: set = set()
    page = api.list_jobs(state=args.state, kind=args.kind, limit=args.limit)
    while True:
        ids = [field_of(job, "id") for job in page]
        if seen.intersection(ids):  # a server that ignores ?before= (an older fpscan) pages for ever
            raise RuntimeError("the server answered a page of jobs it had already listed (it does not page with "
                               "?before=); list fewer with --limit, or update the server")
        seen.update(ids)
        jobs += page
        if len(page) < args.limit:
            return jobs
        more = api.list_jobs(state=args.state, kind=args.kind, limit=1 if not args.all else args.limit,
                             before=field_of(page[-1], "id"))
        if not args.all:
            if more:
                print(f"fpscan jobs list: the {len(jobs)} newest shown; more with --all or --limit",
                      file=sys.stderr)
            return jobs
        page = more


def _what(job: object) -> str:  # a Job model or its dict
    """What a job works on: ``plan 1a2b3c4d on fp1`` for a scan; for a reconstruction its method,
    input and what the input samples: ``nedner of scan 5e6f7a8b (equisteradian, 400 of 9216
    points)``, ``nedner of dataset 8bf03875 sampled by plan 3c4d5e6f (...)``, ``ner of dataset
    8bf03875 (full 96×96)``."""
    from fpscan.clients.http import field_of, to_dict

    p = to_dict(field_of(job, "params")) or {}
    if field_of(job, "kind") == "scan":
        return f"plan {str(p.get('plan_id') or '?')[:8]} on {p.get('scanner_id') or '?'}"
    source = (f"scan {str(p['scan_job_id'])[:8]}" if p.get("scan_job_id")
              else f"dataset {str(p.get('dataset_id') or '?')[:8]}")
    mask = p.get("mask")
    if not p.get("scan_job_id") and isinstance(mask, dict) and mask.get("plan_id"):
        source += f" sampled by plan {str(mask['plan_id'])[:8]}"
    words = mask_words(mask)
    return f"{p.get('method') or '?'} of {source}" + (f" ({words})" if words else "")


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

    from fpscan.clients.cli.common import ProgressBar, full_job_id, make_client
    from fpscan.clients.http import field_of, to_dict

    with make_client(args) as api:
        if args.action == "list":
            jobs = _listed(api, args)
            if args.json:
                print(json.dumps([to_dict(j) for j in jobs], indent=2))
                return 0
            if args.ids:
                print("\n".join(str(field_of(j, "id")) for j in jobs))
                return 0
            # short ids (a unique prefix is accepted wherever a job id is)
            print(f"{'id':<12}  {'kind':<5}  {'state':<10}  {'what':<58}  progress")
            for j in jobs:
                prog = to_dict(field_of(j, "progress")) or {}
                frac = prog.get("fraction")
                if isinstance(frac, (int, float)) and not isinstance(frac, bool) and 0 <= frac <= 1:
                    pct = f"{100 * frac:5.1f}%"
                else:  # none given, or not a fraction (NaN fails 0 <= frac): not shown as one
                    pct = "    ?" if frac is not None else ""
                print(f"{field_of(j, 'id')!s:<12.12}  {field_of(j, 'kind')!s:<5}  "
                      f"{field_of(j, 'state')!s:<10}  {_what(j):<58}  {pct} {prog.get('stage') or ''}".rstrip())
            return 0
        if args.action == "get":
            print(json.dumps(to_dict(api.get_job(args.job_id)), indent=2))
            return 0
        if args.action == "delete":
            delete_each(args.job_ids, api.delete_job, what=lambda gone: f"{gone.get('kind')}, ")
            return 0
        if args.action == "resume":
            job_id = full_job_id(api, args.job_id)
            api.resume_scan(job_id)
            job = api.get_job(job_id)
            print(f"{job_id}: {field_of(job, 'state')} (follow it: fpscan jobs wait {job_id[:12]})")
            return 0
        if args.action == "cancel":
            api.cancel_job(args.job_id)
            job = api.get_job(args.job_id)
            print(f"{args.job_id}: {field_of(job, 'state')}")
            return 0
        # wait
        with ProgressBar(f"job {args.job_id[:8]}", quiet=args.quiet) as bar:
            job = api.wait(args.job_id, on_progress=bar, timeout=args.timeout)
        print(f"{args.job_id}: {field_of(job, 'state')}")
        return 0
