"""`python -m services credentials`: a run's credentials for services started by hand (docs/security.md).

Makes a new run secret and one credential file per identity in OUT (a 0700 folder; files 0600): service
credentials for actor, learner, recorder, launcher and perception (they hold the run secret), teacher
credentials for each teacher id (their own key only). With `--teacher` and an existing OUT it adds one teacher
credential to a run whose secret is there (what the console, or a person's teacher, gets). Then start each
service with `--run RUN --credentials OUT/<identity>.json`.
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path

from common.config import option
from common.protocol import SERVICE_ROLES, validate_name


@dataclass(frozen=True)
class CredentialsConfig:
    """Make a run's credentials (one file per service and teacher) for services started by hand, or add a
    teacher's credential to a run (`--teacher ID` on an existing folder)."""

    run: str = option("live", "run name the credentials are for")
    out: str = option("credentials", "folder to write (0700): run.secret and <identity>.json files (0600)")
    teachers: tuple[str, ...] = option(("oracle",), "teacher ids to make teacher credentials for")
    teacher: str | None = option(
        None,
        "only add a credential for this teacher id, to the run whose secret is in "
        "--out (what the console or a person's teacher process gets)",
    )

    def __post_init__(self):
        validate_name(self.run, "run")
        for t in (*self.teachers, *([self.teacher] if self.teacher else [])):
            validate_name(t, "teacher")


def credentials(cfg: CredentialsConfig) -> int:
    from common.wire.auth import SECRET_FILE, AuthError, make_run_credentials, make_teacher_credential

    out = Path(cfg.out)
    try:
        if cfg.teacher:
            path = make_teacher_credential(out, cfg.run, cfg.teacher)
            print(f"wrote {path}: start teacher {cfg.teacher!r} with --run {cfg.run} --credentials {path}")
            return 0
        paths = make_run_credentials(out, cfg.run, services=SERVICE_ROLES, teachers=cfg.teachers)
    except (AuthError, OSError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return 2
    print(
        f"wrote {out / SECRET_FILE} and credentials for run {cfg.run!r}; start each service with "
        f"--run {cfg.run} --credentials {out}/<identity>.json:"
    )
    for identity, path in paths.items():
        print(f"  {identity:<20} {path}")
    return 0
