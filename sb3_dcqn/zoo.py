"""RL Baselines3 Zoo glue: make ``--algo dcqn`` available to the zoo's commands (the ``dcqn-zoo`` console script).

:func:`register_dcqn` adds DCQN to the zoo's tables; :func:`main` runs one of the zoo's commands, named as in the zoo's
own CLI (``train`` when the first argument is an option)::

    dcqn-zoo train --algo dcqn --env CartPole-v1 -f logs/                  # -conf defaults to the shipped dcqn.yml
    dcqn-zoo --algo dcqn --env CartPole-v1 -optimize --storage dcqn.log     # train without the command word
    dcqn-zoo enjoy --algo dcqn --env CartPole-v1 -f logs/ -n 1000 --no-render
    dcqn-zoo record_video --algo dcqn --env CartPole-v1 -f logs/ -n 500 -o videos/
    dcqn-zoo plot_train -a dcqn -e CartPole-v1 -f logs/ -w 20 -o curve.png   # -o FILE: ours, saved with Agg

The zoo's commands run as they are (none of their functions replaced): ``dcqn-zoo`` reads and checks what they will
read first (the entry and ``-params``, through :mod:`sb3_dcqn.zoo_entry` as ``dcqn-campusnav`` reads them; the trained
agent, by the zoo's ``get_model_path``) and bridges three gaps of rl_zoo3 2.9: ``train``'s evaluation envs and
``record_video`` lack the entry's ``env_kwargs``; ``-n -5`` trains the entry's budget (refused). Registers no env
(:mod:`sb3_dcqn.campusnav.zoo` registers CampusNav's; ``--gym-packages`` others'); needs the zoo extra.
"""

from __future__ import annotations

import argparse
import ast
import contextlib
import functools
import importlib
import io
import os
import runpy
import shutil
import sys
import types
import warnings
from collections.abc import Callable, Collection
from pathlib import Path
from typing import Any, NoReturn

from stable_baselines3.common.off_policy_algorithm import OffPolicyAlgorithm

from sb3_dcqn.dcqn import DCQN
from sb3_dcqn.route_memory.layer import algorithm_class_for, saved_algorithm_class
from sb3_dcqn.zoo_entry import EntryError, ZooEntry, load_zoo_entry, read_params
from sb3_dcqn.zoo_files import EVALUATED_KEYS, default_hyperparams_path, hyperparams_namespace

ALGO_NAME = "dcqn"


def register_dcqn() -> None:
    """Add DCQN to the RL Zoo's algorithm, sampler and converter tables (idempotent; ``-optimize`` samples the zoo's
    DQN search space: DCQN has DQN's hyperparameters)."""
    try:
        from rl_zoo3 import exp_manager, hyperparams_opt, utils
    except ImportError as error:
        raise ImportError('The RL Zoo integration needs rl_zoo3: pip install "sb3-dcqn[zoo]"') from error
    # rl_zoo3 has no plugin hook: its modules import these dicts by name, so adding to them reaches every user
    utils.ALGOS[ALGO_NAME] = DCQN
    hyperparams_opt.HYPERPARAMS_SAMPLER[ALGO_NAME] = hyperparams_opt.HYPERPARAMS_SAMPLER["dqn"]
    hyperparams_opt.HYPERPARAMS_CONVERTER[ALGO_NAME] = hyperparams_opt.convert_offpolicy_params
    # The experiment manager eval()s policy_kwargs and replay buffer strings in its module's globals, nowhere else
    vars(exp_manager).update(hyperparams_namespace())


# The zoo's commands, named as in rl_zoo3/cli.py (which lacks record_video: the zoo runs it as a module)
COMMANDS: dict[str, str] = {
    "train": "train (or -optimize) an agent; the default when the first argument is an option",
    "enjoy": "run a trained agent and print its episode rewards (rl_zoo3.enjoy)",
    "record_video": "record a video of a trained agent (rl_zoo3.record_video)",
    "plot_train": "plot the training episode rewards from the monitor logs (rl_zoo3.plots.plot_train; -o FILE saves)",
    "plot_from_file": "plot results post-processed by all_plots (rl_zoo3.plots.plot_from_file)",
    "all_plots": "plot the evaluations of runs and tabulate them (rl_zoo3.plots.all_plots)",
}
_HELP_FLAGS = ("-h", "--help")
# The zoo's commands whose -n/--n-timesteps counts steps
_STEP_COMMANDS = ("train", "enjoy", "record_video")
# The zoo's commands that take --env and --num-threads; those that load a trained agent
_THREADED_COMMANDS = ("train", "enjoy")
_LOADING_COMMANDS = ("enjoy", "record_video")


def usage() -> str:
    """The overview of ``dcqn-zoo``'s commands (printed by ``dcqn-zoo -h`` and on an unknown command)."""
    width = max(map(len, COMMANDS))
    lines = [
        "usage: dcqn-zoo [COMMAND] [OPTIONS ...]",
        "",
        "Runs a command of the RL Baselines3 Zoo with DCQN registered (--algo dcqn).",
        "",
        "commands:",
        *(f"  {name:<{width}}  {text}" for name, text in COMMANDS.items()),
        "",
        "'dcqn-zoo COMMAND -h' shows the options of a command.",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None, single_thread_envs: Collection[str] = ()) -> None:
    """
    Entry point of ``dcqn-zoo``: registers DCQN, then runs the zoo command named by the first argument.

    Without a command word (first argument an option) the command is ``train``, whose ``-conf`` defaults to the
    shipped ``dcqn.yml`` (see :func:`_train`). Bad input is one line on stderr, exit 2: rl_zoo3 not installed (even
    for ``-h``), an unknown command, a ``-n`` that is not a positive number of steps, a bad hyperparameter entry.

    :param argv: The arguments (default: ``sys.argv[1:]``)
    :param single_thread_envs: Env ids for which ``train`` and ``enjoy`` use one torch thread (``--num-threads 1``)
        unless the arguments give ``--num-threads``: envs whose small networks run slower on more threads
    :raises SystemExit: 2 on bad input, 130 on Ctrl-C before the zoo catches it, else as the zoo's commands exit
    """
    require_zoo(argv)
    args = list(sys.argv[1:] if argv is None else argv)
    if not args:
        print(usage(), file=sys.stderr)
        raise SystemExit(2)
    asks_for_help = any(arg in _HELP_FLAGS for arg in args)
    if args[0].startswith("-"):
        command, prog = "train", "dcqn-zoo"
        if asks_for_help:
            print(usage(), end="\n\n", flush=True)  # then the zoo's train help
    else:
        command, args, prog = args[0], args[1:], f"dcqn-zoo {args[0]}"
        if command not in COMMANDS:
            print(usage(), file=sys.stderr)
            print(
                f"\ndcqn-zoo: error: unknown command {command!r} (choose from {', '.join(COMMANDS)})", file=sys.stderr
            )
            raise SystemExit(2)
    options = _options(command, args)
    if command in _STEP_COMMANDS and not asks_for_help:
        _check_timesteps(command, options.n_timesteps)
    register_dcqn()
    runner, args = _prepare(command, _with_default_threads(command, args, options, single_thread_envs), options)
    saved_argv = sys.argv
    sys.argv = [prog, *args]  # argparse takes its usage line's program name from sys.argv[0]
    try:
        runner()
    except KeyboardInterrupt:
        print(f"\n{prog}: interrupted", file=sys.stderr)
        raise SystemExit(130) from None
    finally:
        sys.argv = saved_argv


def require_zoo(argv: list[str] | None = None) -> None:
    """Without ``rl_zoo3``, say how to install it and exit: 0 after the overview for ``-h`` or no args, else 2."""
    try:
        import rl_zoo3  # noqa: F401
    except ImportError as error:
        install = f'the RL Zoo cannot be imported ({error}): pip install "sb3-dcqn[zoo]"'
        args = sys.argv[1:] if argv is None else argv
        if args in ([], *([flag] for flag in _HELP_FLAGS)):
            print(f"{usage()}\n\n{install}")
            raise SystemExit(0) from None
        print(f"dcqn-zoo: {install}", file=sys.stderr)
        raise SystemExit(2) from None


def _options(command: str, args: list[str]) -> argparse.Namespace:
    """The options ``dcqn-zoo`` looks at, read as the zoo's parsers read them (prefixes, ``--name=value``, ``-n5``, its
    defaults); ``-params`` as ``dcqn-campusnav`` reads it (:func:`~sb3_dcqn.zoo_entry.read_params`)."""
    from rl_zoo3.utils import StoreDict

    parser = argparse.ArgumentParser(add_help=False, exit_on_error=False)
    parser.add_argument("--algo", default="ppo")
    parser.add_argument("--env", default="CartPole-v1")
    if command in _LOADING_COMMANDS:  # the trained agent's options, as these commands name them
        parser.add_argument("-f", "--folder", default="rl-trained-agents")
        parser.add_argument("--exp-id", type=int, default=0)
        parser.add_argument("--load-checkpoint")
        for flag in ("--load-best", "--load-last-checkpoint"):
            parser.add_argument(flag, action="store_true")
    else:
        parser.add_argument("-f", "--log-folder", default="logs")
    for flags in (("-n", "--n-timesteps"), ("-conf", "--conf-file"), ("--num-threads",)):
        parser.add_argument(*flags)
    parser.add_argument("--gym-packages", nargs="+", default=[])
    parser.add_argument("-params", "--hyperparams", nargs="+")
    for flags in (("--env-kwargs",), ("--eval-env-kwargs",)):
        parser.add_argument(*flags, nargs="+", action=StoreDict)
    try:
        options = parser.parse_known_args(args)[0]
        # -params as dcqn-campusnav reads it: one meaning of each value in both command lines
        options.params_text = options.hyperparams
        options.hyperparams = None if options.hyperparams is None else read_params(options.hyperparams)
    except argparse.ArgumentError as error:
        _refuse(command, str(error))
    except EntryError as error:
        _refuse(command, str(error))
    except (NameError, SyntaxError) as error:  # the zoo's StoreDict evaluates the values as Python
        _refuse(command, _first_line(error) + _EVALUATED_VALUE_HINT)
    return options


def _check_timesteps(command: str, value: str | None) -> None:
    """Refuse a ``-n``/``--n-timesteps`` that is not a positive whole number (the zoo reads -5 as "not given")."""
    if value is None:
        return
    try:
        steps = int(value)  # as argparse's type=int reads it
    except ValueError:
        steps = 0
    if steps < 1:
        _refuse(command, f"-n/--n-timesteps: expected a positive number of steps, got {value!r}")


def _with_default_threads(
    command: str, args: list[str], options: argparse.Namespace, single_thread_envs: Collection[str]
) -> list[str]:
    """``args`` with ``--num-threads 1`` added for an env of ``single_thread_envs`` (none given, command takes it)."""
    env_id = options.env.rpartition(":")[2]  # "module:EnvId" names EnvId too
    if command in _THREADED_COMMANDS and env_id in single_thread_envs and options.num_threads is None:
        return [*args, "--num-threads", "1"]
    return args


def _prepare(command: str, args: list[str], options: argparse.Namespace) -> tuple[Callable[[], None], list[str]]:
    """The function that runs ``command`` (it parses ``sys.argv``) and the arguments to give it."""
    help_asked = any(arg in _HELP_FLAGS for arg in args)
    if command == "train":
        return _prepare_train(args, options)
    if command == "enjoy":
        from rl_zoo3 import enjoy  # its Hub download imports requests, which our zoo extra declares

        if not help_asked:
            _found_model(command, options)
        return enjoy.enjoy, args
    if command == "record_video":
        runner = functools.partial(runpy.run_module, "rl_zoo3.record_video", run_name="__main__")  # a script
        return runner, args if help_asked else _with_saved_env_kwargs(args, options, _found_model(command, options))
    if command == "plot_train":
        output, args = _pop_plot_output(args)
        if output is not None:
            import matplotlib

            matplotlib.use("Agg")  # no window: the figure goes to the file
        return (lambda: _plot_train(_import_plots().plot_train, output)), args
    return getattr(_import_plots(), command), args


def _prepare_train(args: list[str], options: argparse.Namespace) -> tuple[Callable[[], None], list[str]]:
    """The zoo's ``train`` (``-conf`` defaulting to the shipped ``dcqn.yml``) once its entry is checked; its evaluation
    envs get the entry's ``env_kwargs`` unless env kwargs are given (rl_zoo3 2.9 gives them only ``--env-kwargs``)."""
    from rl_zoo3.train import train

    if any(arg in _HELP_FLAGS for arg in args):
        return train, args
    if options.conf_file is None:
        options.conf_file = str(default_hyperparams_path())
        args = [*args, "-conf", options.conf_file]
    args = _params_for_zoo(args, options)
    entry = _checked_entry(options)
    if entry is not None and entry.env_kwargs and options.env_kwargs is None and options.eval_env_kwargs is None:
        args = [*args, "--eval-env-kwargs", *(f"{key}:{value!r}" for key, value in entry.env_kwargs.items())]
    run = _next_run_folder(options)
    return (lambda: _train(train, None if entry is None else entry.source, run)), args


def _params_for_zoo(args: list[str], options: argparse.Namespace) -> list[str]:
    """``args`` with ``-params`` as :func:`~sb3_dcqn.zoo_entry.read_params` read them, in the zoo's syntax (its
    ``StoreDict`` evaluates each value as Python): a plain value as its literal (``lin_3e-4`` as the string YAML made
    of it), a string the zoo evaluates itself (``policy_kwargs``, the replay buffer's keys) as that string."""
    if options.hyperparams is None:
        return args
    parser = argparse.ArgumentParser(add_help=False, exit_on_error=False)
    parser.add_argument("-params", "--hyperparams", nargs="+")
    texts = {key.strip(): text.strip() for key, _, text in (item.partition(":") for item in options.params_text)}
    items = []
    for key, value in options.hyperparams.items():
        if not _is_literal(value) and key not in EVALUATED_KEYS:
            _refuse("train", f"-params {key}: {texts[key]!r} is not a value the zoo's -params can take")
        items.append(f"{key}:{value!r}" if _is_literal(value) else f"{key}:{texts[key]!r}")
    return [*parser.parse_known_args(args)[1], "-params", *items]


def _is_literal(value: Any) -> bool:
    """Whether ``repr(value)`` is a Python literal that evaluates back to ``value`` (numbers, strings, containers)."""
    try:
        return ast.literal_eval(repr(value)) == value
    except (ValueError, SyntaxError):
        return False


def _checked_entry(options: argparse.Namespace) -> ZooEntry | None:
    """The entry the zoo will read (``-params`` applied), checked now; ``None`` where the zoo reads no YAML entry (a
    Python config) or will refuse the command line itself (an unknown env or algorithm)."""
    import gymnasium as gym
    from rl_zoo3.exp_manager import ExperimentManager
    from rl_zoo3.utils import ALGOS

    algo, env_id, conf = options.algo, options.env, options.conf_file
    try:
        for package in options.gym_packages:  # as the zoo imports them, so that their envs are known
            importlib.import_module(package)
    except ImportError:
        return None
    if algo not in ALGOS or env_id not in gym.registry or not conf.endswith((".yml", ".yaml")):
        return None
    fallbacks = ("atari", "default") if ExperimentManager.is_atari(env_id) else ("default",)
    algorithm = getattr(ALGOS[algo], "bare_class", ALGOS[algo])  # as registered, whatever an earlier run set
    try:
        entry = load_zoo_entry(conf, env_id, options.hyperparams, fallbacks, algorithm)
        entry.budget(None if options.n_timesteps is None else int(options.n_timesteps))
    except EntryError as error:
        _refuse("train", str(error))
    # The zoo builds ALGOS[algo](**entry) and has no hook for the class: set, for this run, the one that takes the entry
    ALGOS[algo] = algorithm_class_for(algorithm, entry.hyperparams)
    return entry


def _next_run_folder(options: argparse.Namespace) -> Path | None:
    """The folder the zoo's run will write (``logs/dcqn/CartPole-v1_3``), named by the zoo's rule and functions."""
    from rl_zoo3.utils import EnvironmentName, get_latest_run_id

    log_path = f"{options.log_folder}/{options.algo}/"  # as the zoo's ExperimentManager names it
    try:
        env_name = EnvironmentName(options.env)
    except ValueError:  # more than one colon: the zoo refuses it
        return None
    return Path(log_path) / f"{env_name}_{get_latest_run_id(log_path, env_name) + 1}"


def _train(train: Callable[[], None], source: str | None, run: Path | None) -> None:
    """Run the zoo's ``train``: bad input it meets before training is one line (an env or model the entry cannot set
    up named by ``source``), exit 2; a run that fails before it wrote results leaves no folders made for it."""
    existed = (
        set() if run is None else {*_run_folders(run), *(p for p in (run.parent, run.parent.parent) if p.exists())}
    )
    try:
        train()
    except BaseException as error:
        if run is not None and not (isinstance(error, SystemExit) and error.code in (0, None)):
            _remove_unfinished_run(run, existed)
        if isinstance(error, _INPUT_ERRORS) and not _raised_in(error, *_TRAINING):
            where = f"{source}: " if source is not None and _raised_in(error, "setup_experiment") else ""
            _refuse("train", where + _first_line(error))
        raise


def _raised_in(error: BaseException, *methods: str) -> bool:
    """Whether ``error`` was raised inside one of these methods of the zoo's ``ExperimentManager``."""
    from rl_zoo3.exp_manager import ExperimentManager

    codes = {getattr(ExperimentManager, name).__code__ for name in methods}
    traceback = error.__traceback__
    while traceback is not None:
        if traceback.tb_frame.f_code in codes:
            return True
        traceback = traceback.tb_next
    return False


def _found_model(command: str, options: argparse.Namespace) -> str:
    """The run folder of the agent ``enjoy`` or ``record_video`` will load, by the zoo's ``get_model_path``: one that is
    not there is one line (the zoo's ``enjoy`` would try the Hugging Face Hub, ``record_video`` raise)."""
    from rl_zoo3.utils import ALGOS, EnvironmentName, get_model_path

    try:
        with contextlib.redirect_stdout(io.StringIO()):  # the zoo says which run it loads when it runs
            found = get_model_path(
                options.exp_id,
                options.folder,
                options.algo,
                EnvironmentName(options.env),
                options.load_best,
                options.load_checkpoint,
                options.load_last_checkpoint,
            )
    except (AssertionError, ValueError) as error:
        _refuse(command, f"{error} (-f names the log folder of the trained agents)")
    # The zoo loads ALGOS[algo] and has no hook for the class of a file: a model saved wearing the route memory
    # is loaded by the class that wears it (the bare class would drop the memory)
    bare = getattr(ALGOS.get(options.algo), "bare_class", ALGOS.get(options.algo))
    if isinstance(bare, type) and issubclass(bare, OffPolicyAlgorithm):
        ALGOS[options.algo] = saved_algorithm_class(found[1], bare)
    return os.path.join(found[2], str(EnvironmentName(options.env)))


# What the zoo raises on bad input before training: its checks, SB3's and the envs' (assertions, wrong values or
# keywords), evaluated strings; raised inside these ExperimentManager methods, it is an error while training
_INPUT_ERRORS = (AssertionError, ImportError, KeyError, TypeError, ValueError, NameError, SyntaxError)
_TRAINING = ("learn", "hyperparameters_optimization", "save_trained_model")
_EVALUATED_VALUE_HINT = " (--env-kwargs values are Python: quote strings, e.g. encoder:'pixels')"
# Files that make a run folder worth keeping: models and checkpoints, evaluations, saved replay buffers
_RESULT_SUFFIXES = (".zip", ".npz", ".pkl")


def _run_folders(run: Path) -> list[Path]:
    """The run's folder as the zoo made it: ``run``, or with ``-uuid`` the same and a suffix (``_<uuid>``)."""
    return [
        path
        for path in run.parent.glob(f"{run.name}*")
        if path.name == run.name or path.name.startswith(f"{run.name}_")
    ]


def _remove_unfinished_run(run: Path, existed: set[Path]) -> None:
    """Remove a failed run's folder when it holds no results, and the log folders made for it if left empty."""
    for folder in _run_folders(run):
        if folder not in existed and folder.is_dir() and not _holds_results(folder):
            shutil.rmtree(folder, ignore_errors=True)
    for folder in (run.parent, run.parent.parent):
        if folder not in existed and folder.is_dir() and not any(folder.iterdir()):
            folder.rmdir()


def _holds_results(folder: Path) -> bool:
    """Whether a run folder holds a model, evaluations, a replay buffer or a finished episode's monitor line."""
    for path in folder.rglob("*"):
        if path.suffix in _RESULT_SUFFIXES:
            return True
        if path.name.endswith("monitor.csv"):
            with open(path) as file:
                if sum(1 for _ in file) > 2:  # a JSON line and the column names, then one line an episode
                    return True
    return False


def _first_line(error: BaseException) -> str:
    return f"{type(error).__name__}: {(str(error).strip().splitlines() or [''])[0]}"


def _refuse(command: str, message: str) -> NoReturn:
    """One line on stderr, exit 2: how ``dcqn-zoo`` reports bad input."""
    print(f"dcqn-zoo {command}: error: {message}", file=sys.stderr)
    raise SystemExit(2)


def _with_saved_env_kwargs(args: list[str], options: argparse.Namespace, stats_path: str) -> list[str]:
    """``args`` with the run's saved ``env_kwargs`` (the command line's winning) as a last ``--env-kwargs``, the one the
    zoo's parser keeps: rl_zoo3 2.9's ``record_video`` ignores them (CampusNav's ``view_dim``), its ``enjoy`` not."""
    from rl_zoo3.utils import get_saved_hyperparams

    env_kwargs = {**(get_saved_hyperparams(stats_path)[0].get("env_kwargs") or {}), **(options.env_kwargs or {})}
    return [*args, "--env-kwargs", *(f"{key}:{value!r}" for key, value in env_kwargs.items())] if env_kwargs else args


def _pop_plot_output(args: list[str]) -> tuple[str | None, list[str]]:
    """Split ``-o FILE``/``--output FILE`` (this script's option of ``plot_train``) from ``args``."""
    parser = argparse.ArgumentParser(add_help=False, exit_on_error=False)
    parser.add_argument("-o", "--output")
    try:
        options, rest = parser.parse_known_args(args)
    except argparse.ArgumentError as error:
        _refuse("plot_train", str(error))
    return options.output, rest


def _import_plots() -> types.ModuleType:
    """``rl_zoo3.plots``, or an error naming the packages of the zoo's ``plots`` extra that it imports."""
    try:
        from rl_zoo3 import plots
    except ModuleNotFoundError as error:
        # rl_zoo3.plots imports all three plot scripts, so each command needs seaborn and scipy
        raise SystemExit(
            f"dcqn-zoo: the plot commands need the packages of the zoo's plots extra, {error.name!r} is missing: "
            "pip install seaborn scipy (and rliable for plot_from_file -r)"
        ) from error
    return plots


def _plot_train(plot_train: Callable[[], None], output: str | None) -> None:
    """Run the zoo's ``plot_train``; with ``output``, save the figure there instead of showing it."""
    if output is None:
        plot_train()
        return
    from matplotlib import pyplot as plt

    with warnings.catch_warnings():  # Agg (set for -o) cannot show: plot_train's closing plt.show() does nothing
        warnings.simplefilter("ignore", UserWarning)
        plot_train()
    plt.savefig(output)
    print(f"Saved the figure to {output}")


if __name__ == "__main__":
    main()
