"""The main job: train DCQN on CampusNav, close a road, re-train, and report routes before and after.

Run as ``dcqn-campusnav`` (or ``python -m sb3_dcqn.campusnav_job``). Steps:

1. Train DCQN on ``CampusNav-v0`` (the built-in campus, goal Dreese Lab) with the env's entry of
   ``hyperparams/dcqn.yml`` (zoo format), logging to TensorBoard.
2. Evaluate the greedy policy from every (start intersection, heading) and print success rate, SPL, coverage and
   mean steps against the shortest path.
3. Close the road that the learned routes use most (among those whose closure keeps the goal reachable), evaluate
   again, continue training for ``--retrain-timesteps`` and evaluate once more: the re-adaptation.
4. Write route pictures (original route vs re-routed, closure marked), the model, and a summary (JSON and Markdown).
   Route scores also go to TensorBoard under ``routes/``.
"""

from __future__ import annotations

import argparse
import json
import time
from collections import Counter
from pathlib import Path
from typing import Any

import gymnasium as gym
import numpy as np
import torch as th
import yaml
from stable_baselines3.common.callbacks import BaseCallback
from stable_baselines3.common.monitor import Monitor
from torch import nn

import campusnav_env  # noqa: F401  (registers the CampusNav ids)
from campusnav_env import RoadClosureError, road_key
from campusnav_env.atomic_files import write_png, write_text_atomic
from campusnav_env.rendering.map_view import draw_map
from campusnav_env.route_evaluation import RouteReport, evaluate_routes
from sb3_dcqn.dcqn import DCQN
from sb3_dcqn.fusion import EmbeddingFusionExtractor
from sb3_dcqn.zoo import default_hyperparams_path

# Names that policy_kwargs strings in the YAML may use, as in the RL Zoo
_YAML_NAMESPACE = {"dict": dict, "nn": nn, "EmbeddingFusionExtractor": EmbeddingFusionExtractor}
# Keys of a zoo entry that configure the zoo's env/wrappers rather than the algorithm
_ZOO_ONLY_KEYS = ("n_envs", "normalize", "env_wrapper", "frame_stack", "callback", "vec_env_wrapper")


def load_zoo_entry(path: str | Path, env_id: str) -> tuple[int, dict[str, Any]]:
    """
    Read one env's entry of a zoo-format hyperparameter file.

    :param path: The YAML file
    :param env_id: The env id (top-level key)
    :return: ``(n_timesteps, algorithm keyword arguments)``; ``policy_kwargs`` strings are evaluated
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"hyperparameter file not found: {path}")
    with open(path) as file:
        table = yaml.safe_load(file) or {}
    if env_id not in table:
        raise KeyError(f"{path}: no entry for {env_id!r} (entries: {sorted(table)})")
    entry = dict(table[env_id])
    if "n_timesteps" not in entry:
        raise KeyError(f"{path}: entry {env_id!r} has no 'n_timesteps'")
    n_timesteps = int(entry.pop("n_timesteps"))
    for key in _ZOO_ONLY_KEYS:
        entry.pop(key, None)
    if isinstance(entry.get("policy_kwargs"), str):
        try:
            entry["policy_kwargs"] = eval(entry["policy_kwargs"], dict(_YAML_NAMESPACE))
        except Exception as error:
            raise ValueError(f"{path}: {env_id!r}: cannot evaluate policy_kwargs {entry['policy_kwargs']!r}") from error
    return n_timesteps, entry


class ProgressPrinter(BaseCallback):
    """Prints steps, episodes, recent success rate and elapsed time every ``every`` steps."""

    def __init__(self, phase: str, every: int = 5_000) -> None:
        super().__init__()
        self.phase = phase
        self.every = every
        self._start = time.perf_counter()

    def _on_step(self) -> bool:
        if self.n_calls % self.every == 0:
            successes = [float(success) for success in self.model.ep_success_buffer]
            rate = f"{np.mean(successes):.2f}" if successes else "-"
            print(
                f"[{self.phase}] {self.num_timesteps} steps, {self.model._episode_num} episodes, "
                f"success (last {len(successes)} episodes) {rate}, {time.perf_counter() - self._start:.0f} s",
                flush=True,
            )
        return True


def most_used_closable_road(env: Any, report: RouteReport) -> tuple[int, int]:
    """The road most traversed by the report's routes whose closure keeps the goals reachable everywhere."""
    usage: Counter[tuple[int, int]] = Counter()
    for route in report.routes:
        for u, v in zip(route.nodes[:-1], route.nodes[1:], strict=True):
            usage[road_key(u, v)] += 1
    for road, _ in usage.most_common():
        try:
            env.close_road(*road)
        except RoadClosureError:
            continue
        env.reopen_road(*road)
        return road
    raise RuntimeError("no road on the learned routes can be closed without cutting a goal off")


def _log_routes(model: DCQN, tag: str, report: RouteReport) -> None:
    for name, value in report.summary().items():
        model.logger.record(f"routes/{tag}_{name}", value)
    model.logger.dump(model.num_timesteps)


def _table(rows: dict[str, RouteReport]) -> str:
    lines = [
        "| phase | success rate | SPL | coverage (start nodes) | mean steps | mean shortest path | routes |",
        "|---|---|---|---|---|---|---|",
    ]
    for phase, report in rows.items():
        s = report.summary()
        lines.append(
            f"| {phase} | {s['success_rate']:.3f} | {s['spl']:.3f} | {s['coverage']:.3f} | {s['mean_steps']:.2f} | "
            f"{s['mean_shortest']:.2f} | {int(s['n_routes'])} |"
        )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> dict[str, Any]:
    th.set_num_threads(args.threads)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    n_timesteps, kwargs = load_zoo_entry(args.conf, args.env)
    if args.timesteps is not None:
        n_timesteps = args.timesteps
    retrain_timesteps = args.retrain_timesteps if args.retrain_timesteps is not None else n_timesteps // 3
    env_kwargs: dict[str, Any] = {"encoder": args.encoder}
    if args.encoder_weights is not None:
        env_kwargs["encoder_kwargs"] = {"weights_path": args.encoder_weights}
    if args.render_size is not None:
        from campusnav_env.rendering.street_view import RenderSettings

        env_kwargs["render_settings"] = RenderSettings(width=args.render_size[0], height=args.render_size[1])
    env = Monitor(gym.make(args.env, **env_kwargs))
    nav = env.unwrapped

    def policy(observations: Any) -> np.ndarray:
        return model.predict(observations, deterministic=True)[0]

    model = DCQN(env=env, tensorboard_log=str(out / "tb"), seed=args.seed, verbose=args.verbose, **kwargs)

    def train(steps: int, phase: str) -> float:
        """Train (continuing the same TensorBoard run after the first phase); returns the seconds it took."""
        start = time.perf_counter()
        model.learn(
            steps,
            callback=ProgressPrinter(phase, args.report_every),
            tb_log_name="DCQN",
            reset_num_timesteps=phase == "train",
            progress_bar=args.progress,
        )
        return time.perf_counter() - start

    print(f"training DCQN on {args.env} for {n_timesteps} steps", flush=True)
    train_seconds = train(n_timesteps, "train")
    trained = evaluate_routes(nav, policy)
    _log_routes(model, "trained", trained)

    road = tuple(args.close_road) if args.close_road else most_used_closable_road(nav, trained)
    nav.close_road(*road)
    closed = evaluate_routes(nav, policy)
    _log_routes(model, "after_closure", closed)
    print(f"road {road[0]}-{road[1]} closed; training {retrain_timesteps} more steps", flush=True)
    retrain_seconds = train(retrain_timesteps, "re-train")
    readapted = evaluate_routes(nav, policy)
    _log_routes(model, "readapted", readapted)

    # Route picture: the longest learned route that used the closed road, before and after re-training
    road_set = {road}
    affected = [
        r
        for r in trained.routes
        if any(road_key(u, v) in road_set for u, v in zip(r.nodes[:-1], r.nodes[1:], strict=True))
    ]
    example = max(affected, key=lambda r: len(r.nodes)) if affected else trained.routes[0]
    rerouted = next(r for r in readapted.routes if (r.start, r.heading) == (example.start, example.heading))
    picture = draw_map(
        nav.graph,
        goal=nav.goal_nodes[0],
        agent=example.start,
        heading=example.heading,
        # Drawn in this order: the agent's route after re-training ends on top
        routes={
            "shortest path after closure": nav.graph.shortest_path(example.start, nav.goal_nodes[0]),
            "learned route": list(example.nodes),
            "re-routed after closure": list(rerouted.nodes),
        },
    )
    write_png(out / "routes.png", picture)
    model.save(out / "dcqn_campusnav")

    phases = {"trained": trained, "road closed": closed, "re-trained": readapted}
    summary = {
        "env": args.env,
        "encoder": args.encoder,
        "n_timesteps": n_timesteps,
        "retrain_timesteps": retrain_timesteps,
        "train_seconds": train_seconds,
        "retrain_seconds": retrain_seconds,
        "episodes": len(env.get_episode_rewards()),
        "closed_road": list(road),
        "routes_using_closed_road": len(affected),
        "example_start": [example.start, example.heading],
        **{f"{phase}": report.summary() for phase, report in phases.items()},
    }
    table = _table(phases)
    text = (
        f"# DCQN on {args.env}\n\n{n_timesteps} steps ({train_seconds:.0f} s), then road {road[0]}-{road[1]} closed "
        f"({len(affected)} learned routes used it) and {retrain_timesteps} more steps ({retrain_seconds:.0f} s).\n\n"
        f"{table}\n"
    )
    write_text_atomic(out / "summary.md", text)
    write_text_atomic(out / "summary.json", json.dumps(summary, indent=2))
    print(text)
    print(f"TensorBoard: tensorboard --logdir {out / 'tb'}   route picture: {out / 'routes.png'}")
    return summary


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--env", default="CampusNav-v0", help="env id (default: %(default)s)")
    parser.add_argument("--conf", default=str(default_hyperparams_path()), help="zoo-format hyperparameter YAML")
    parser.add_argument("--timesteps", type=int, default=None, help="override the YAML's n_timesteps")
    parser.add_argument("--retrain-timesteps", type=int, default=None, help="steps after the closure (default: 1/3)")
    parser.add_argument("--close-road", type=int, nargs=2, metavar=("U", "V"), help="road to close (default: busiest)")
    parser.add_argument("--encoder", default="efficientnet-lite0", help="view encoder (default: %(default)s)")
    parser.add_argument("--encoder-weights", help="weights file for the encoder (e.g. torchvision's ResNet-50)")
    parser.add_argument("--render-size", type=int, nargs=2, metavar=("W", "H"), help="street-view size (640 480)")
    parser.add_argument("--out", default="runs/campusnav", help="output directory (default: %(default)s)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--threads", type=int, default=1, help="torch threads (default: %(default)s)")
    parser.add_argument("--report-every", type=int, default=5_000, help="print progress every N steps")
    parser.add_argument("--verbose", type=int, default=0, help="SB3 verbosity (1 prints its training tables)")
    parser.add_argument(
        "--progress", action="store_true", help="show SB3's training progress bar (needs the rich package)"
    )
    return parser


def main(argv: list[str] | None = None) -> None:
    run(build_parser().parse_args(argv))


if __name__ == "__main__":
    main()
