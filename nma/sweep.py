"""A `--multirun` sweep: the jobs it launches and their checks before it starts (job_overrides,
checking), and a table across its jobs, written when the sweep ends (any launcher).

Hydra calls `SweepSummary.on_multirun_end` in the launching process once every job has returned
(conf/config.yaml registers it under hydra.callbacks).  It reads each job directory's
`.hydra/overrides.yaml` and `metrics.json` and writes `summary.json` and `summary.md` into the sweep
directory: per job its overrides, final metric and failed solves, or why it failed (its FAILED_JOB
file), or that it left no metrics (still running).
"""

from __future__ import annotations

import itertools
import json
import logging
import sys
import time
from pathlib import Path

import yaml
from hydra.experimental.callback import Callback

log = logging.getLogger(__name__)
FAILED_JOB = "failed.json"  # in a sweep job's directory: the job failed (its exit code and why)
# the last sweep this process summarised: its failed jobs
last = {"failed": [], "jobs": 0, "summary": None}


def job_overrides(overrides: list[str], multirun: bool) -> list[list[str]]:
    """The override list of every job Hydra's basic sweeper would launch (one without
    --multirun)."""
    if not multirun:
        return [overrides]
    from hydra.core.override_parser.overrides_parser import OverridesParser

    choices = []
    for o in OverridesParser.create().parse_overrides(overrides):
        if o.is_sweep_override():
            key = o.get_key_element()
            choices.append([f"{key}={v}" for v in o.sweep_string_iterator()])
        else:
            choices.append([o.input_line])
    return [list(job) for job in itertools.product(*choices)]


def checking(
    jobs: list,
    multirun: bool,
    rank: int = 0,
    first: float = 2.0,
    every: float = 10.0,
    clock=time.monotonic,
    out=None,
):
    """(number, overrides) of each job that nma.cli.preflight checks before a sweep starts.  Where
    the checks take longer than `first` seconds, rank 0 says on stderr what they are and, every
    `every` seconds, how many jobs are done, and at the end how long they took (each job's config
    is composed and checked as Hydra will run it: a sweep of hundreds of jobs takes minutes)."""
    out = out or sys.stderr
    start = last = clock()
    said = False
    for num, job in enumerate(jobs):
        now = clock()
        if multirun and rank == 0 and now - last >= (every if said else first):
            what = (
                "checking the sweep's jobs before any starts, each config composed and checked "
                "as it will run: "
                if not said
                else "checking the sweep's jobs: "
            )
            print(f"{what}{num} of {len(jobs)} done, {now - start:.0f} s", file=out, flush=True)
            said, last = True, now
        yield num, job
    if said:
        print(
            f"checked the sweep's {len(jobs)} jobs in {clock() - start:.0f} s", file=out, flush=True
        )


def summarise(sweep_dir: Path) -> dict:
    """Write summary.{json,md} for the job directories under `sweep_dir`; returns the JSON body."""
    sweep_dir = Path(sweep_dir)
    jobs = []
    for overrides in sorted(
        sweep_dir.glob("*/.hydra/overrides.yaml"), key=lambda p: _job_key(p.parent.parent.name)
    ):
        job_dir = overrides.parent.parent
        row = {
            "job": job_dir.name,
            "overrides": yaml.safe_load(overrides.read_text()) or [],
            "dir": str(job_dir),
        }
        metrics, failed = job_dir / "metrics.json", job_dir / FAILED_JOB
        if failed.exists():
            row.update(value=None, failed=json.loads(failed.read_text()))
        elif metrics.exists():
            m = json.loads(metrics.read_text())
            row.update(
                {
                    k: m.get(k)
                    for k in (
                        "task",
                        "metric",
                        "value",
                        "unit",
                        "no_actuation",
                        "steps",
                        "failed_solves",
                    )
                }
            )
            row["samples"] = len(m.get("per_sample") or [])
        else:
            row["value"] = None
        jobs.append(row)
    body = {"sweep_dir": str(sweep_dir), "jobs": jobs}
    (sweep_dir / "summary.json").write_text(json.dumps(body, indent=1))
    lines = [
        "| job | overrides | metric | value | failed solves | at rest, no actuation | steps |",
        "|---|---|---|---|---|---|---|",
    ]
    for j in jobs:
        if "failed" in j:
            value = f"failed (exit {j['failed']['exit_code']}): {j['failed']['error']}"
        else:
            value = (
                "no metrics (unfinished)" if j["value"] is None else f"{j['value']:.4g} {j['unit']}"
            )
        solves = (
            f"{j['failed_solves']} of {j['samples']}" if j.get("failed_solves") is not None else ""
        )
        rest = "" if j.get("no_actuation") is None else f"{j['no_actuation']:.4g}"
        lines.append(
            f"| {j['job']} | {' '.join(j['overrides'])} | {j.get('metric') or ''} | {value} | "
            f"{solves} | {rest} | {j.get('steps') or ''} |"
        )
    (sweep_dir / "summary.md").write_text("\n".join(lines) + "\n")
    return body


def _job_key(name: str):
    return (0, int(name), "") if name.isdigit() else (1, 0, name)


class SweepSummary(Callback):
    def on_multirun_end(self, config, **kwargs) -> None:
        sweep_dir = Path(config.hydra.sweep.dir)
        if sweep_dir.is_dir():
            body = summarise(sweep_dir)
            last.update(
                failed=[j["job"] for j in body["jobs"] if "failed" in j],
                jobs=len(body["jobs"]),
                summary=sweep_dir / "summary.md",
            )
            log.info("sweep summary: %s", sweep_dir / "summary.md")
