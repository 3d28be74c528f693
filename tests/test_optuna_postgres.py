"""The Optuna sweep on several machines: two ``dcqn-zoo -optimize`` workers share one study in a PostgreSQL server.

The test starts a real PostgreSQL server of its own (``initdb`` and ``pg_ctl`` in a temp folder, listening on a free
localhost port, trust authentication) with a fresh database ``optuna_<random>``, then runs two worker processes of
README's sweep command against ``--storage postgresql+psycopg://optuna@127.0.0.1:PORT/optuna_...`` at once, each in
a folder of its own as on two machines: CampusNav-v0 from the shipped entry as README's command runs it (no
``--env-kwargs``, so the entry's own ``env_kwargs``, ``view_dim: 64`` with EfficientNet-Lite0 views, make the
training and the evaluation envs; each worker encodes the campus's views once into its own feature cache), two
trials each, a few hundred steps per trial. Optuna's tables are created once before they start, as README says;
neither creates the study beforehand: the first to arrive does, the other joins. The study must hold the four
completed trials, numbered 0-3 with no number twice, two from each worker (each worker's log names the trials it
finished). The server is stopped and its folder removed at the end, also when the test fails.

PostgreSQL refuses to run as root. Run as root, the test runs ``initdb`` and ``pg_ctl`` as an existing unprivileged
account (``postgres``, as the Debian package creates it, else ``nobody``) through ``subprocess``'s ``user``/``group``
arguments, in a temp folder handed to that account; it creates no account. The workers run as the test's own user
and connect over TCP.

Given a server instead (``SWEEP_TEST_POSTGRES_URL``: the SQLAlchemy URL of a database the test may create databases
from, e.g. ``postgresql+psycopg://optuna@127.0.0.1:5433/postgres``, as CI's ``.ci/integration`` starts one), the test
starts none: it creates a database of its own in that server and drops it at the end.

Needs the PostgreSQL binaries (on ``PATH`` or in ``/usr/lib/postgresql/<version>/bin``; skipped without them) unless
given a server, and the driver psycopg 3 (``pip install "sb3-dcqn[sweep]"``; skipped without it). Marked slow;
``.ci/integration`` runs it with everything installed and fails where it would be skipped.
"""

from __future__ import annotations

import os
import pwd
import re
import secrets
import shutil
import socket
import subprocess
import sys
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager, nullcontext
from pathlib import Path

import pytest

pytest.importorskip("rl_zoo3")
optuna = pytest.importorskip("optuna")
psycopg = pytest.importorskip("psycopg", reason='the PostgreSQL driver: pip install "sb3-dcqn[sweep]"')

pytestmark = pytest.mark.slow

DATABASE_USER = "optuna"
# A server given by the caller (CI starts one): the SQLAlchemy URL of a database to connect to for CREATE DATABASE
SERVER_URL_VARIABLE = "SWEEP_TEST_POSTGRES_URL"
STUDY = "campusnav-postgres"
WORKERS = 2
TRIALS_PER_WORKER = 2
# Accounts that may run the server when the test runs as root (PostgreSQL refuses root); none is created
SERVER_ACCOUNTS = ("postgres", "nobody")
SERVER_TIMEOUT_S = 60
WORKER_TIMEOUT_S = 600
# README's sweep command with a small budget: the shipped CampusNav-v0 entry (its env_kwargs reach the trials' eval
# envs only through dcqn-zoo: --env-kwargs would hide that) and one torch thread (dcqn-zoo's default for CampusNav)
SWEEP_ARGS = [
    "--algo", "dcqn", "--env", "CampusNav-v0", "-f", "logs",
    "-optimize", "--study-name", STUDY, "--n-trials", str(TRIALS_PER_WORKER), "--n-jobs", "1",
    "--sampler", "random", "--pruner", "none", "-n", "400", "--n-evaluations", "1", "--eval-episodes", "2",
    "--no-optim-plots", "--seed", "0",
]  # fmt: skip
FINISHED_TRIAL = re.compile(r"Trial (\d+) finished")


def postgres_binary(name: str) -> str | None:
    """``initdb``, ``pg_ctl`` or ``postgres`` on ``PATH``, else in the newest ``/usr/lib/postgresql/*/bin``."""
    found = shutil.which(name)
    if found:
        return found
    versions = sorted(Path("/usr/lib/postgresql").glob("*/bin"), key=lambda p: p.parent.name, reverse=True)
    return next((str(folder / name) for folder in versions if (folder / name).is_file()), None)


def server_account() -> pwd.struct_passwd | None:
    """The account the server runs as: ``None`` (this process's own) unless running as root."""
    if os.geteuid() != 0:
        return None
    for name in SERVER_ACCOUNTS:
        try:
            return pwd.getpwnam(name)
        except KeyError:
            continue
    pytest.skip(f"running as root, and none of the accounts {SERVER_ACCOUNTS} exists to run PostgreSQL as")


def free_port() -> int:
    with socket.socket() as probe:
        probe.bind(("127.0.0.1", 0))
        return probe.getsockname()[1]


def run_as(account: pwd.struct_passwd | None, command: list[str], cwd: Path) -> None:
    """Run a server command as ``account`` (None: as this process), failing with its output."""
    ids = {} if account is None else {"user": account.pw_uid, "group": account.pw_gid, "extra_groups": []}
    result = subprocess.run(
        command, cwd=cwd, capture_output=True, text=True, timeout=SERVER_TIMEOUT_S, check=False, **ids
    )
    if result.returncode != 0:
        raise RuntimeError(f"{' '.join(command)} failed ({result.returncode}):\n{result.stdout}\n{result.stderr}")


@contextmanager
def fresh_database(server_url: str) -> Iterator[str]:
    """A new, empty database in the server at ``server_url`` (a SQLAlchemy URL); its URL. Dropped afterwards."""
    from sqlalchemy.engine import make_url

    server = make_url(server_url)
    name = f"optuna_{secrets.token_hex(4)}"  # never one that a rerun or another test run already made
    connect = {"host": server.host, "port": server.port, "user": server.username, "password": server.password}
    # autocommit: CREATE and DROP DATABASE cannot run in a transaction
    with psycopg.connect(**connect, dbname=server.database, autocommit=True) as db:
        db.execute(f"CREATE DATABASE {name}")
    try:
        yield server.set(drivername="postgresql+psycopg", database=name).render_as_string(hide_password=False)
    finally:
        with psycopg.connect(**connect, dbname=server.database, autocommit=True) as db:
            db.execute(f"DROP DATABASE {name} WITH (FORCE)")  # FORCE: a worker killed on a timeout may hold it


@contextmanager
def own_server() -> Iterator[str]:
    """A fresh PostgreSQL server of the test's own; the SQLAlchemy URL of its database ``postgres``. Stopped and
    removed afterwards."""
    binaries = {name: postgres_binary(name) for name in ("initdb", "pg_ctl", "postgres")}
    missing = [name for name, path in binaries.items() if path is None]
    if missing:
        pytest.skip(
            f"PostgreSQL binaries not found: {', '.join(missing)} (not on PATH nor in /usr/lib/postgresql), "
            f"and no server given in ${SERVER_URL_VARIABLE}"
        )
    account = server_account()
    # In the system temp dir, not pytest's: the server's account must reach it (pytest's base folder is root's, 0700)
    root = Path(tempfile.mkdtemp(prefix="optuna-postgres-"))
    data = root / "data"
    started = False
    try:
        if account is not None:
            os.chown(root, account.pw_uid, account.pw_gid)
        initdb = [binaries["initdb"], "-D", str(data), "-U", DATABASE_USER, "--auth=trust", "--no-locale"]
        run_as(account, [*initdb, "-E", "UTF8", "--no-sync"], root)
        port = free_port()
        options = f"-c listen_addresses=127.0.0.1 -p {port} -c unix_socket_directories={root} -c fsync=off"
        start = [binaries["pg_ctl"], "-D", str(data), "-l", str(root / "server.log"), "-o", options]
        run_as(account, [*start, "-w", "-t", str(SERVER_TIMEOUT_S), "start"], root)
        started = True
        yield f"postgresql+psycopg://{DATABASE_USER}@127.0.0.1:{port}/postgres"
    finally:
        if started:
            run_as(account, [binaries["pg_ctl"], "-D", str(data), "-m", "fast", "-w", "stop"], root)
        shutil.rmtree(root, ignore_errors=True)


@pytest.fixture
def postgres_url() -> Iterator[str]:
    """The SQLAlchemy URL of an empty database for the study: in the server of ``$SWEEP_TEST_POSTGRES_URL`` where
    given, else in a server of the test's own."""
    given = os.environ.get(SERVER_URL_VARIABLE)
    with nullcontext(given) if given else own_server() as server_url, fresh_database(server_url) as database_url:
        yield database_url


def start_worker(storage: str, folder: Path) -> subprocess.Popen:
    """One ``dcqn-zoo`` sweep worker (the console script's code) in ``folder``, as on a machine of its own."""
    folder.mkdir()
    code = "import sys; from sb3_dcqn.campusnav.zoo import main; main(sys.argv[1:])"
    env = {**os.environ, "CAMPUSNAV_CACHE": str(folder / "cache")}
    return subprocess.Popen(
        [sys.executable, "-c", code, *SWEEP_ARGS, "--storage", storage],
        cwd=folder,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )


def test_two_sweep_workers_share_one_study_in_postgresql(postgres_url: str, tmp_path: Path) -> None:
    # README's step before the workers start: Optuna's tables, created once (workers that start at once on an empty
    # database each create them, and all but one fail: optuna/optuna#1092; 7 rounds of 8 here without this line)
    optuna.storages.RDBStorage(postgres_url).engine.dispose()
    workers = [start_worker(postgres_url, tmp_path / f"machine-{i}") for i in range(WORKERS)]
    outputs = []
    try:
        for worker in workers:
            outputs.append(worker.communicate(timeout=WORKER_TIMEOUT_S))
    finally:
        for worker in workers:
            if worker.poll() is None:
                worker.kill()
                worker.wait()
    for worker, (_, stderr) in zip(workers, outputs, strict=True):
        assert worker.returncode == 0, stderr[-3000:]

    study = optuna.load_study(study_name=STUDY, storage=postgres_url)
    numbers = sorted(trial.number for trial in study.trials)
    assert numbers == list(range(WORKERS * TRIALS_PER_WORKER))
    assert all(trial.state == optuna.trial.TrialState.COMPLETE for trial in study.trials), study.trials
    # Optuna logs each finished trial (to stderr) in the process that ran it
    finished_by = [{int(n) for n in FINISHED_TRIAL.findall(stderr)} for _, stderr in outputs]
    assert all(len(finished) == TRIALS_PER_WORKER for finished in finished_by), finished_by
    assert set.union(*finished_by) == set(numbers)
    for i in range(WORKERS):  # each worker's report of the study, as on its own machine
        assert list((tmp_path / f"machine-{i}" / "logs" / "dcqn").glob("report_*.csv")), f"machine-{i}"
