"""A ``dcqn-campusnav`` training run: build a new one (``train``, ``demo``) or load a saved one (``readapt``,
``train -i``), train it with its closures, and finish it (pictures, model, summary), all in the run's folder.

A :class:`Run` holds what the steps share: the request, the env settings, the model and its envs, the folder, the
closures and budgets, the levers and callbacks. Its folder never replaces an earlier run's results
(:func:`~sb3_dcqn.campusnav.output_paths.free_folder`: ``runs/x`` taken, ``runs/x_2``); the summary, curves and pictures
describe the model saved beside them (the last route evaluation is of the model as saved). Bad input raises
:class:`~sb3_dcqn.campusnav.errors.CommandError` before anything is trained or written; Ctrl-C while training saves
the run's model and raises :class:`Interrupted`.
"""

from __future__ import annotations

import json
import sys
import warnings
import zipfile
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.vec_env import DummyVecEnv

from campusnav_env import CampusNavEnv
from campusnav_env.recovery import RouteEvaluation
from sb3_dcqn.campusnav import experiments
from sb3_dcqn.campusnav.closure_checks import check_plan, closure_plan, plan_source, road_refused
from sb3_dcqn.campusnav.entries import (
    check_device,
    checked_params,
    conf_entry,
    parse_params,
    training_budget,
    training_entry,
)
from sb3_dcqn.campusnav.env_checks import env_creator, env_error, env_settings
from sb3_dcqn.campusnav.errors import PROG, CommandError, Interrupted, note
from sb3_dcqn.campusnav.experiments import ClosurePlan, TrainingOutcome
from sb3_dcqn.campusnav.levers import LEVERS, lever_callbacks
from sb3_dcqn.campusnav.model_checks import MODEL_FILES, MODEL_NAME, find_model, saved_run
from sb3_dcqn.campusnav.model_files import SavedRun, model_paths, save_model
from sb3_dcqn.campusnav.output_paths import DEFAULT_OUT, free_folder, moved_note
from sb3_dcqn.campusnav.requests import Request
from sb3_dcqn.campusnav.settings import DEFAULT_ENV, EnvSettings
from sb3_dcqn.dcqn import DCQN
from sb3_dcqn.route_memory.layer import algorithm_name, saved_algorithm_class

__all__ = ["Checkpoints", "Run", "load_model", "make_env", "restore_closures"]

_IMAGE_ONLY_TO_TENSORBOARD = ("stdout", "log", "json", "csv")
# Hyperparameters a loaded model keeps whatever -params says: they shape the networks or the buffer it was built with
_BUILT_WITH = ("policy", "policy_kwargs", "replay_buffer_class", "replay_buffer_kwargs", "buffer_size", "n_envs")


# ------------------------------------------------------------------------------------------------ envs and models
def _training_envs(request: Request, settings: EnvSettings, n_envs: int, seed: int) -> tuple[DummyVecEnv, CampusNavEnv]:
    """Training envs (each in a ``Monitor``) and the first one's CampusNav env, which the route evaluation shares."""
    from campusnav_env.env import UnknownGoalError
    from sb3_dcqn.campusnav.settings import campus_of, make_training_envs

    try:
        venv = make_training_envs(settings, n_envs, seed)
    except (TypeError, ValueError, UnknownGoalError) as error:  # e.g. an env_kwargs value the env refuses
        raise env_error(settings, error, request) from None
    try:
        return venv, campus_of(venv.envs[0])
    except TypeError as error:
        raise CommandError(f"--env {settings.env_id}: {error}") from None


def make_env(settings: EnvSettings, request: Request) -> CampusNavEnv:
    """One env, for evaluating and drawing (``request``: the command line, for the words of an error)."""
    from campusnav_env.env import UnknownGoalError
    from sb3_dcqn.campusnav.settings import make_env as make

    try:
        return make(settings)
    except (TypeError, ValueError, UnknownGoalError) as error:  # e.g. an env_kwargs value the env refuses
        raise env_error(settings, error, request) from None


def restore_closures(
    navs: Sequence[CampusNavEnv], model: Path, saved: SavedRun, open_map: bool
) -> list[tuple[int, int]]:
    """
    Close the roads that were closed when the model was saved (``closed_roads_at_save``) in every env, unless
    ``--open-map``; say which closures are in force.

    :return: the roads closed
    """
    if saved.settings is None:  # saved by DCQN.save, or its settings file lost: say so, never score it silently
        note(
            f"{model}: no {model_paths(model)[2].name} beside it, so the closures it was trained under are not "
            "known; starting from the open map (plus the --close roads)"
        )
    if not saved.closed_roads:
        return []
    roads = ", ".join(f"{u}-{v}" for u, v in saved.closed_roads)
    if open_map:
        note(f"the open map (--open-map); the model was saved with roads {roads} closed")
        return []
    from campusnav_env.maps.refusals import Refusal

    for nav in navs:
        for u, v in saved.closed_roads:
            try:
                nav.close_road(u, v, force=True)  # as they were when it was saved
            except Refusal as error:  # not on this map
                raise CommandError(
                    f"{model}: closed_roads_at_save {u}-{v}: {road_refused(error)}; pass --open-map to start from the "
                    "open map"
                ) from None
    note(f"roads closed when the model was saved, closed again: {roads} (--open-map: none)")
    return list(saved.closed_roads)


def load_model(
    path: Path,
    settings: EnvSettings,
    nav: CampusNavEnv,
    venv: DummyVecEnv | None = None,
    device: str | None = None,
    **changes: Any,
) -> DCQN:
    """
    Load a model for ``nav``'s observations, onto ``venv`` to train on (else onto ``nav``: a model with SB3's
    ``HerReplayBuffer`` builds its buffer with the env, so it loads only with one).

    :param changes: Attributes to change when loading (``-params``)
    """
    import pickle
    import zlib

    from stable_baselines3.common.save_util import json_to_data

    unreadable = (KeyError, EOFError, OSError, RuntimeError, zipfile.BadZipFile, zlib.error, pickle.UnpicklingError)
    try:  # the spaces it was saved with, read before loading (SB3's own refusal is a bare ValueError)
        with zipfile.ZipFile(path) as archive:
            saved_space = json_to_data(archive.read("data").decode()).get("observation_space")
        model = None
        if saved_space == nav.observation_space:
            env = venv if venv is not None else DummyVecEnv([lambda: nav])
            model = saved_algorithm_class(path, DCQN).load(path, env=env, device=device or "auto", **changes)
    except (*unreadable, ValueError) as error:
        raise CommandError(f"{path}: not a readable model file ({error!r}); {MODEL_FILES}") from None
    if model is None:
        raise CommandError(
            f"{path}: the model's observations do not match those of {settings.describe()}; pass the --env, "
            "--encoder and --render-size it was trained with"
        )
    return model


def _new_logger(model: DCQN, out: Path, verbose: int) -> Path:
    """Log this run to ``out/tb/DCQN_<n>`` (``DCQN-memory_<n>`` wearing the memory; a new folder), one logger for
    every ``learn`` call."""
    from stable_baselines3.common.logger import configure
    from stable_baselines3.common.utils import get_latest_run_id

    name = algorithm_name(model, for_files=True)  # DCQN, or DCQN-memory where it wears the route memory
    folder = out / "tb" / f"{name}_{get_latest_run_id(str(out / 'tb'), name) + 1}"
    model.set_logger(configure(str(folder), ["tensorboard", *(["stdout"] if verbose >= 2 else [])]))
    return folder


def _make_callbacks(specs: Sequence[tuple[str, dict[str, Any]]]) -> list[BaseCallback]:
    """New callbacks from ``(class path, keyword arguments)`` specs, as the zoo builds an entry's ``callback``."""
    from sb3_dcqn.zoo_entry import ZooEntry

    try:
        return ZooEntry(n_timesteps=0, hyperparams={}, callbacks=tuple(specs)).make_callbacks()
    except (ImportError, AttributeError, TypeError, ValueError) as error:
        raise CommandError(f"callback {specs!r}: cannot be built ({error})") from None


def _curves_note(callbacks: Sequence[BaseCallback]) -> str | None:
    """The training curves' note: a start curriculum's episodes start near the goal, so their reward runs ahead of
    the route success from every start."""
    from campusnav_env.callbacks import StartCurriculumCallback
    from campusnav_env.figures import CURRICULUM_NOTE

    return CURRICULUM_NOTE if any(isinstance(c, StartCurriculumCallback) for c in callbacks) else None


# ------------------------------------------------------------------------------------------------ levers of a saved run
def _saved_levers(request: Request, saved: SavedRun) -> tuple[str, ...]:
    """
    A saved run's levers: those given, else the model's own. A lever that sets DCQN's or the env's options, or a
    replay variant the model's buffer lacks, must be one the model was trained with (a loaded model keeps what it was
    built with); callback levers (the boost) can be added.
    """
    from sb3_dcqn.campusnav.levers import replay_variants

    trained = tuple(saved.levers or ())
    if request.levers is None:
        return trained
    built_with = set(replay_variants(trained))

    def addable(name: str) -> bool:
        lever = LEVERS[name]
        return not (lever.dcqn_options or lever.env_options) and set(lever.replay_variants) <= built_with

    for name in request.levers:
        if not addable(name) and name not in trained:
            with_ = ", ".join(trained) or ("none" if saved.levers is not None else "not recorded")
            raise CommandError(
                f"--levers {name}: {LEVERS[name].name} is set when a model is built, and this model was trained "
                f"without it (its levers: {with_}); {request.command} adds only the callback levers "
                f"({', '.join(n for n in LEVERS if addable(n))}); train a new model with --levers {name} instead"
            )
    return tuple(request.levers)


def _saved_callbacks(request: Request, saved: SavedRun, env_id: str) -> tuple[tuple[str, dict[str, Any]], ...]:
    """
    The hyperparameter entry's callbacks (e.g. a start curriculum) to go on with: ``--conf``'s entry when given,
    else those saved with the model, else (a model saved without them) the shipped entry's.
    """
    if request.conf is None and saved.callbacks is not None:
        return saved.callbacks
    try:
        return conf_entry(request.conf, env_id).callbacks
    except CommandError:
        if request.conf is not None:
            raise
        return ()  # no shipped entry for this env: no callbacks to restore


def _load_changes(request: Request) -> dict[str, Any]:
    """``-params`` for a loaded model: checked as the YAML's keys; those it was built with cannot change."""
    changes = parse_params(request.params)
    fixed = sorted(set(changes) & {*_BUILT_WITH, "n_timesteps"})
    if fixed:
        raise CommandError(
            f"-params {', '.join(fixed)}: set when a model is built (or, n_timesteps, by --timesteps); a loaded "
            "model keeps them"
        )
    return checked_params(changes)


# ------------------------------------------------------------------------------------------------ checkpoints
class Checkpoints(BaseCallback):
    """
    ``--save-freq N``: every N env steps the model, its replay buffer (if the run saves one) and its env settings to
    ``checkpoints/dcqn_campusnav_<steps>_steps.zip`` (each file atomically), so that ``train -i`` goes on from any.
    """

    def __init__(self, run: Run, every: int) -> None:
        super().__init__()
        self.run = run
        self.every = max(every // run.venv.num_envs, 1)  # calls, each of n_envs steps (as the RL Zoo counts)
        self.asked = every
        self.written = 0

    def _on_step(self) -> bool:
        if self.n_calls % self.every == 0:
            path = self.run.out / "checkpoints" / f"{MODEL_NAME}_{self.num_timesteps}_steps.zip"
            self.run.save(path, replay_buffer=self.run.replay_buffer)
            self.written += 1
        return True

    def say_if_none(self, steps: int, keep_training: bool) -> None:
        """A run that ended before its first checkpoint says so and why: the user asked for checkpoints."""
        if self.written:
            return
        why = (
            "--timesteps is below --save-freq"
            if keep_training
            else "a run stops once solved and recovered; add --keep-training to train the whole --timesteps budget"
        )
        note(f"no checkpoint written: training ended after {steps} steps, before --save-freq {self.asked} ({why})")


# ------------------------------------------------------------------------------------------------ the run
@dataclass
class Run:
    """
    One training run and everything its steps share.

    :param request: The command line
    :param settings: The env it trains on
    :param model: The model (new or loaded), on ``venv``
    :param venv: The training envs
    :param nav: The first training env's CampusNav env (the route evaluation's, the closures')
    :param out: Its folder (never an earlier run's)
    :param model_path: Where the model is saved
    :param plan: Its closures
    :param budgets: Steps of the first phase and after each one-at-a-time closure
    :param levers: The re-adaptation levers it trains with
    :param callback_specs: Its hyperparameter entry's callbacks, saved with the model
    :param title: The summary's heading
    :param from_model: It went on from a saved model (``readapt``, ``train -i``)
    :param replay_buffer: Save the replay buffer with the model
    :param origin: The model it went on from, if any
    :param asked_out: The folder asked for (``out``, unless that holds an earlier run's results)
    """

    request: Request
    settings: EnvSettings
    model: DCQN
    venv: DummyVecEnv
    nav: CampusNavEnv
    out: Path
    model_path: Path
    plan: ClosurePlan
    budgets: tuple[int, int]
    levers: tuple[str, ...]
    callback_specs: tuple[tuple[str, dict[str, Any]], ...]
    title: str
    from_model: bool = False
    replay_buffer: bool = True
    origin: Path | None = None
    asked_out: Path | None = None
    callbacks: list[BaseCallback] = field(default_factory=list)
    tb_folder: Path | None = None

    # -------------------------------------------------------------------------------------------- build or load
    @classmethod
    def new(cls, request: Request, plan: ClosurePlan, title: str, replay_buffer: bool) -> Run:
        """A new model (``train``, ``demo``), with ``plan``'s closures, in a folder of its own."""
        asked = Path(request.out if request.out is not None else DEFAULT_OUT[request.command])
        out = free_folder(asked, request.force)
        env_id = request.env or DEFAULT_ENV
        creator = env_creator(env_id)
        entry, levers = training_entry(request, env_id)
        budget = training_budget(entry, request.timesteps)
        check_device(request.device)
        settings = env_settings(request, entry=entry, creator=creator)
        recovery_budget = max(1, budget // 2) if request.recovery_budget is None else request.recovery_budget
        n_envs = entry.n_envs if request.n_envs is None else request.n_envs
        venv, nav = _training_envs(request, settings, n_envs, request.seed)
        check_plan(plan, nav, plan_source(request))
        device = {"device": request.device} if request.device else {}
        try:
            model = entry.make_model(venv, seed=request.seed, verbose=int(request.verbose >= 2), **device)
        except (ValueError, TypeError, AssertionError) as error:  # settings DCQN refuses together, SB3's asserts
            raise CommandError(f"--conf: {entry.source}: {error}") from None
        if levers:
            title += f" (re-adaptation levers: {', '.join(levers)})"
        run = cls(
            request, settings, model, venv, nav, out, out / f"{MODEL_NAME}.zip", plan, (budget, recovery_budget),
            levers, entry.callbacks, title, replay_buffer=replay_buffer, asked_out=asked,
        )  # fmt: skip
        described = f", levers: {' '.join(levers)}" if levers else ""
        print(
            f"training DCQN on {settings.describe()}: up to {budget} steps, {n_envs} env(s){described}", file=sys.stderr
        )
        return run._ready([*lever_callbacks(levers), *entry.make_callbacks()])

    @classmethod
    def readapt(cls, request: Request) -> Run:
        """``readapt``: a saved model with new closures, trained on until recovered."""
        assert request.model is not None
        path = find_model(request.model)
        plan = closure_plan(request)
        if plan.empty:
            raise CommandError(
                "readapt: give the roads to close (--close, --close-random, --close-on-route or --closures)"
            )
        if request.in_place:
            # The model replaced, so are the results beside it: a summary there describes the model there
            if request.out is not None and Path(request.out).resolve() != path.parent.resolve():
                raise CommandError(
                    f"--out {request.out}: --in-place writes the re-adapted model and its results beside {path} "
                    "(replacing them); leave out --out, or leave out --in-place"
                )
            given = out = path.parent
        else:
            given = Path(request.out) if request.out is not None else path.parent / "readapt"
            if (given / path.name).resolve() == path.resolve():
                raise CommandError(
                    f"--out {given}: the re-adapted model would overwrite {path}; pass --in-place or another --out"
                )
            out = free_folder(given, request.force)
        target = out / path.name
        steps = request.timesteps or 20_000
        budgets = (steps if plan.scheduled.events else 0, steps)
        return cls._load(request, path, plan, given, out, target, budgets, f"DCQN re-adapted: {path}")

    @classmethod
    def resume(cls, request: Request) -> Run:
        """
        ``train -i MODEL``: go on training a saved run with its levers, callbacks, closures in force and replay
        buffer (the saved closures are in force, not closed again), in a folder of its own (default: the model's
        run folder, which holds it: ``runs/x_2``), for ``--timesteps`` more steps (default: the entry's
        ``n_timesteps``).
        """
        assert request.trained_agent is not None
        path = find_model(request.trained_agent, "--trained-agent")
        plan = closure_plan(request)
        run_folder = path.parent.parent if path.parent.name == "checkpoints" else path.parent
        asked = Path(request.out) if request.out is not None else run_folder
        out = free_folder(asked, request.force)
        saved = saved_run(path)
        env_id = request.env or (saved.settings.env_id if saved.settings else DEFAULT_ENV)
        budget = request.timesteps or training_budget(conf_entry(request.conf, env_id), None)
        recovery_budget = max(1, budget // 2) if request.recovery_budget is None else request.recovery_budget
        title = f"DCQN training, resumed from {path}"
        budgets = (budget, recovery_budget)
        return cls._load(request, path, plan, asked, out, out / f"{MODEL_NAME}.zip", budgets, title)

    @classmethod
    def _load(
        cls,
        request: Request,
        path: Path,
        plan: ClosurePlan,
        asked: Path,
        out: Path,
        target: Path,
        budgets: tuple[int, int],
        title: str,
    ) -> Run:
        """A saved run (readapt, resume): its env, closures in force, levers, callbacks, model and replay buffer."""
        saved = saved_run(path)
        check_device(request.device)
        settings = env_settings(request, saved.settings)
        levers = _saved_levers(request, saved)
        callback_specs = _saved_callbacks(request, saved, settings.env_id)
        changes = _load_changes(request)
        buffer_path = Path(request.replay_buffer) if request.replay_buffer is not None else model_paths(path)[1]
        if request.replay_buffer is not None and not buffer_path.is_file():
            raise CommandError(f"--replay-buffer: file not found: {buffer_path}")
        venv, nav = _training_envs(request, settings, saved.n_envs, request.seed)
        from sb3_dcqn.campusnav.settings import campus_of

        restored = restore_closures([campus_of(env) for env in venv.envs], path, saved, request.open_map)
        check_plan(plan, nav, plan_source(request), restored)
        model = load_model(path, settings, nav, venv, request.device, **changes)
        _check_levers_with_buffer(levers, model)
        model.set_random_seed(request.seed)
        _load_replay_buffer(model, buffer_path)
        if levers:
            title += f" (re-adaptation levers: {', '.join(levers)})"
        run = cls(
            request, settings, model, venv, nav, out, target, plan, budgets, levers, callback_specs, title,
            from_model=True, replay_buffer=not request.no_replay_buffer, origin=path, asked_out=asked,
        )  # fmt: skip
        return run._ready([*lever_callbacks(levers), *_make_callbacks(callback_specs)])

    def _ready(self, callbacks: list[BaseCallback]) -> Run:
        """The folder made, the logger set, the callbacks (``--save-freq``'s checkpoints last) in place."""
        if self.asked_out is not None:
            moved_note(self.asked_out, self.out)
        if self.request.command == "readapt" and self.request.in_place:
            note(f"--in-place: replacing {self.model_path} and the results beside it (summary, pictures, buffer)")
        self.out.mkdir(parents=True, exist_ok=True)
        self.tb_folder = _new_logger(self.model, self.out, self.request.verbose)
        self.callbacks = list(callbacks)
        if self.request.save_freq is not None:
            self.callbacks.append(Checkpoints(self, self.request.save_freq))
        return self

    # -------------------------------------------------------------------------------------------- train, save
    def save(self, path: Path, replay_buffer: bool) -> list[Path]:
        """The model (and its replay buffer) with its env settings and the closures in force, each atomically."""
        return save_model(
            self.model,
            path,
            self.settings,
            sorted(self.nav.closed_roads),
            replay_buffer,
            list(self.levers),
            self.callback_specs,
        )

    def train(self) -> TrainingOutcome:
        """
        Train with the closure plan (:func:`~sb3_dcqn.campusnav.experiments.train_with_closures`, its options from
        the request); on Ctrl-C save the model, its replay buffer and the closures in force (each file atomically),
        evaluate the model saved and write a summary that says the run was interrupted, with those scores, then raise
        :class:`Interrupted` saying how to go on.
        """
        request = self.request
        start = self.model.num_timesteps
        try:
            outcome = experiments.train_with_closures(
                self.model,
                self.plan,
                budget=self.budgets[0],
                recovery_budget=self.budgets[1],
                eval_freq=request.eval_freq,
                recovery_eval_freq=request.recovery_eval_freq,
                stop_when_solved=not request.keep_training,
                stop_when_recovered=not request.keep_training,
                callbacks=self.callbacks,
                verbose=request.verbose,
                progress=request.progress,
            )
        except KeyboardInterrupt as interrupt:
            print(file=sys.stderr)  # past the progress bar
            interrupted = interrupt.outcome if isinstance(interrupt, experiments.TrainingInterrupted) else None
        else:
            for callback in self.callbacks:
                if isinstance(callback, Checkpoints):
                    callback.say_if_none(self.model.num_timesteps - start, request.keep_training)
            return outcome
        saved = self._save_interrupted(interrupted)
        raise Interrupted(
            f"interrupted at step {self.model.num_timesteps}: saved {saved[0]} with its replay buffer and the closures "
            f"in force; go on with '{PROG} train -i {saved[0]}' (or '{PROG} readapt {saved[0]} --in-place --close "
            f"...' to close roads), or in Python with DCQN.load('{saved[0]}', env), load_replay_buffer('{saved[1]}') "
            "and learn(N, reset_num_timesteps=False)"
        ) from None

    def _save_interrupted(self, outcome: TrainingOutcome | None) -> list[Path]:
        """
        After Ctrl-C: the model, its replay buffer and the closures in force, then a summary saying so (whatever
        summary an earlier run left here, with ``--force``, is not of this model), then the saved model's scores in
        it; Ctrl-C again leaves the files written whole (each atomically) and the summary without scores.
        """
        from campusnav_env.atomic_files import write_text_atomic
        from sb3_dcqn.campusnav.summaries import final_json

        try:
            saved = self.save(self.model_path, replay_buffer=True)
            files = {"model": str(saved[0]), "replay_buffer": str(saved[1]), "env_settings": str(saved[2])}
            summary: dict[str, Any] = {
                "command": self.request.command,
                "interrupted": True,
                "algorithm": algorithm_name(self.model),
                "num_timesteps": self.model.num_timesteps,
                "settings": self.settings.to_json(),
                "final": None,
                "files": files,
            }
            heading = f"# {self.title}\n\nInterrupted at step {self.model.num_timesteps}: {saved[0]} saved"
            write_text_atomic(self.out / "summary.json", json.dumps(summary, indent=2) + "\n")
            write_text_atomic(self.out / "summary.md", f"{heading}, not evaluated.\n")
            if outcome is not None:
                # Ctrl-C lands anywhere (in a gradient step, while a transition is stored): evaluate the model as saved
                final = outcome.evaluation.evaluate()
                summary["final"] = final_json(final)
                write_text_atomic(self.out / "summary.json", json.dumps(summary, indent=2) + "\n")
                text = f"{heading}; its routes: success {final.success_rate:.3f}, SPL {final.spl:.3f}.\n"
                write_text_atomic(self.out / "summary.md", text)
            self.model.logger.close()
        except KeyboardInterrupt:
            raise Interrupted(
                f"interrupted again while saving to {self.out}: the files written are whole (each is written "
                "atomically), the others not written"
            ) from None
        return saved

    @staticmethod
    def _final_evaluation(outcome: TrainingOutcome) -> RouteEvaluation:
        """
        The evaluation of the model as it is now, which is saved: the last one if nothing has changed the model
        since, else a new one (logged to TensorBoard as every evaluation is). Every number a run reports at its end
        (bars, tables, summaries, TensorBoard's last point) comes from here.
        """
        if not outcome.evaluation.current:
            outcome.evaluation.evaluate()
        return outcome.evaluation.evaluations[-1]

    def finish(self, outcome: TrainingOutcome) -> tuple[dict[str, Any], str]:
        """
        Figures (files and TensorBoard images), model, summary, all of the model as saved; returns the summary and
        its Markdown text (``summary.json``, ``summary.md``). The figures are drawn and the model's files saved before
        any picture is written, and the summary last: a run that fails here leaves no folder that looks finished.
        """
        from stable_baselines3.common.logger import Image

        from campusnav_env.atomic_files import write_text_atomic
        from campusnav_env.figures import training_curves, write_figure
        from sb3_dcqn.campusnav.pictures import picture_goals, routes_figure
        from sb3_dcqn.campusnav.summaries import final_json, outcome_json, run_report

        model, nav, out = self.model, self.nav, self.out
        final = self._final_evaluation(outcome)  # the scores, curves and pictures are of the model saved beside them
        evaluations = outcome.evaluation.evaluations
        recoveries = outcome.recoveries
        files: dict[str, str] = {"tensorboard": str(self.tb_folder)}
        figures: dict[str, np.ndarray] = {}
        routes = routes_figure(nav, evaluations, recoveries, picture_goals(nav))
        if routes is not None:
            figures["routes"] = routes
        figures["curves"] = training_curves(
            outcome.progress.episode_rewards,
            outcome.progress.episode_lengths,
            recoveries or outcome.closures.records,
            evaluations,
            title=f"{algorithm_name(model)} on {self.settings.describe()}",
            note=_curves_note(self.callbacks),
        )
        saved = self.save(self.model_path, self.replay_buffer)  # all serialised first, then written, the zip last
        for name, image in figures.items():
            files[name] = str(write_figure(out / f"{name}.png", image))
            model.logger.record(f"figures/{name}", Image(image, "HWC"), exclude=_IMAGE_ONLY_TO_TENSORBOARD)
        model.logger.dump(model.num_timesteps)
        model.logger.close()

        files["model"] = str(saved[0])
        if self.replay_buffer:
            files["replay_buffer"] = str(saved[1])
        files["env_settings"] = str(saved[-1])
        files["summary"] = str(out / "summary.md")
        files["summary_json"] = str(out / "summary.json")

        ran = f"{algorithm_name(model)} on {self.settings.describe()}"  # DCQN, or DCQN + memory
        text = run_report(self.title, ran, outcome, files, from_model=self.from_model)
        if not self.replay_buffer:
            text += "\nReplay buffer not saved (" + _buffer_switch(self.request.command) + ").\n"
        summary = {
            "command": self.request.command,
            "title": self.title,
            "algorithm": algorithm_name(model),
            "settings": self.settings.to_json(),
            "seed": self.request.seed,
            "levers": list(self.levers),
            "num_timesteps": model.num_timesteps,
            "resumed_from": None if self.origin is None or self.request.command != "train" else str(self.origin),
            **outcome_json(outcome),
            "final": final_json(final),
            "files": files,
        }
        write_text_atomic(out / "summary.md", text)
        write_text_atomic(out / "summary.json", json.dumps(summary, indent=2) + "\n")
        return summary, text


def _buffer_switch(command: str) -> str:
    """The switch that keeps the replay buffer, in words."""
    if command == "demo":
        return f"the demo keeps none; '{PROG} train' saves it, for readapt and train -i"
    return "--no-replay-buffer"


def _check_levers_with_buffer(levers: Sequence[str], model: DCQN) -> None:
    """The levers can run with the loaded model's replay buffer (e.g. boost_on_revision needs DCQN's own)."""
    from sb3_dcqn.campusnav.levers import check_levers

    try:
        check_levers(levers, {"replay_buffer_class": model.replay_buffer_class})
    except ValueError as error:
        raise CommandError(f"--levers: {error}") from None


def _load_replay_buffer(model: DCQN, buffer_path: Path) -> None:
    """The replay buffer saved with the model, if any (else training starts with an empty one)."""
    if not buffer_path.is_file():
        print(f"no replay buffer at {buffer_path}: starting with an empty one", file=sys.stderr)
        return
    with warnings.catch_warnings():
        # SB3's HER buffer ends its last saved episode here, as it should: the run starts new episodes
        warnings.filterwarnings("ignore", message="The last trajectory in the replay buffer will be truncated")
        model.load_replay_buffer(buffer_path)
    assert model.replay_buffer is not None
    if model.replay_buffer.n_envs != model.n_envs:
        raise CommandError(
            f"{buffer_path}: saved with {model.replay_buffer.n_envs} envs, the model trains on {model.n_envs}"
        )
    print(f"replay buffer: {buffer_path} ({model.replay_buffer.size()} transitions)", file=sys.stderr)
