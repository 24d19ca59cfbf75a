"""`python -m services up`: a whole live run on this machine.

Starts an embedded Zenoh router (this process's own session in router mode, listening on HOST:PORT, no
multicast scouting), makes the run's credentials (common/wire/auth.py: a secret per run, one credential file per
service and teacher, readable only by the user), spawns one process per service (recorder, learner, the
teacher's processes, actor; each in its own process group, each told to exit if this process disappears),
shows a progress bar fed by the learner's EpisodeSummary messages, and stops everything at the end or on
Ctrl-C: the launcher announces (its authenticated status 'stopping') that the run is ending and asks the actor
to stop (SIGTERM); the others then finish on their own (teacher -> learner -> recorder); whatever is still
running after `stop_timeout` s gets SIGTERM, then SIGKILL 3 s later. Leaves in OUT/RUN/: session.mcap (and
later segments), summary.json, learning_curve.png, config/<service>.json, logs/<service>.log,
stats/<service>.json, state/ (the learner's checkpoint, the actor's and teachers' progress files),
credentials/ (0700).

Run names are unique (`live-<date>-<time>-<random>`) and the run directory is locked (flock) while a launcher
uses it. Supervision (docs/faults.md): a service that dies (non-zero exit, a signal, or a SIGTERM that the
launcher did not send) or hangs (its liveliness token lapses while its process runs, or no status for
`hang_timeout` s) is killed and started again with the same config after a back-off (`restart_backoff` s,
doubling, at most 8 s), at most `restart_limit` times per service; said on screen and as foxglove.Log records
on `hitl/<run>/log/launcher`, listed in summary.json. Past the limit the run stops (exit code 1). A full disk
(less than `min_free_mb` free, or a service dying of ENOSPC) stops the run cleanly with a one-line error and a
summary.json that says why (its space is reserved at the start). With `security` the embedded router is the
secured one (TLS, user/password, access control: common/security.py) and every service connects with it.

Modules: config (UpConfig, the processes), children (start/stop processes), supervise (restarts, hangs),
rundir (name, lock, credentials, disk), report (progress, summary), run (the loop).
"""

from services.launcher.children import ROOT, Child, child_env, spawn, stop_children
from services.launcher.config import Launch, UpConfig, build_processes
from services.launcher.report import finish, latency_table, percentiles
from services.launcher.rundir import default_run_name
from services.launcher.run import up

__all__ = [
    "ROOT",
    "Child",
    "child_env",
    "spawn",
    "stop_children",
    "Launch",
    "UpConfig",
    "build_processes",
    "finish",
    "latency_table",
    "percentiles",
    "default_run_name",
    "up",
]
