"""The rough edges of ``dcqn-campusnav`` that a new user met, each fed through the command line as that user did.

Every bad input ends with a message that names the file, key, line, flag or road, and exit status 2, before anything
is trained or written, and nothing saved is lost. ``--help`` is plain text and quick: the command line's module
imports neither torch nor SB3 nor CampusNav. Pictures are titled with start, goal, closures and score, and road ids
can be found from the command line (``roads NODE``, ``draw --node-ids``).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from sb3_dcqn.campusnav import cli as campusnav_cli
from sb3_dcqn.campusnav import pictures
from sb3_dcqn.campusnav.cli import build_parser, main, run

FAST = ("--encoder", "pixels", "--render-size", "64", "48")
GOOD_CONF = """\
CampusNav-v0:
  n_timesteps: 200
  policy: 'MultiInputPolicy'
  env_kwargs:
    view_dim: 16
  learning_rate: !!float 1e-3
  buffer_size: 500
  learning_starts: 100
"""
DEAD_END = ("0", "11")  # node 0 of the built-in campus has this road only: closing it cuts Dreese Lab off from it
REST_MARKUP = ("``", ":mod:", ":func:", ":class:", ":meth:", ":data:")


# The session's feature cache: the views are rendered and encoded once, not once per test or module (conftest.py)
pytestmark = pytest.mark.usefixtures("shared_feature_cache")


@pytest.fixture(scope="module")
def saved_model(tmp_path_factory: pytest.TempPathFactory) -> bytes:
    """The bytes of a real saved DCQN model (CartPole: the errors below come before its env matters)."""
    from sb3_dcqn import DCQN

    path = tmp_path_factory.mktemp("model") / "model.zip"
    DCQN("MlpPolicy", "CartPole-v1", policy_kwargs={"net_arch": [8]}).save(path)
    return path.read_bytes()


def fails(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[str, str]:
    """Run the command line, expect exit status 2 and return (stdout, the error line)."""
    with pytest.raises(SystemExit) as exit_info:
        main(argv)
    assert exit_info.value.code == 2
    printed = capsys.readouterr()
    return printed.out, printed.err


def files_under(folder: Path) -> dict[str, bytes]:
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


# ------------------------------------------------------------------------------------------------ hyperparameter files
def test_a_misspelt_hyperparameter_names_the_file_and_the_key(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    conf = tmp_path / "mine.yml"
    conf.write_text(GOOD_CONF.replace("learning_rate", "learnig_rate"))
    out = tmp_path / "out"
    _, error = fails(["train", *FAST, "--conf", str(conf), "--out", str(out)], capsys)
    assert f"--conf: {conf}: entry 'CampusNav-v0': learnig_rate: unknown DCQN hyperparameter" in error
    assert "did you mean 'learning_rate'?" in error
    assert not out.exists()  # before any work


def test_a_misspelt_policy_or_env_kwargs_key_names_it(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    conf = tmp_path / "mine.yml"
    conf.write_text(GOOD_CONF + "  policy_kwargs: 'dict(net_arc=[16])'\n")
    _, error = fails(["train", *FAST, "--conf", str(conf), "--out", str(tmp_path / "out")], capsys)
    assert f"{conf}: entry 'CampusNav-v0': policy_kwargs: unknown key 'net_arc' of MultiInputPolicy" in error
    assert "(did you mean 'net_arch'?)" in error
    conf.write_text(GOOD_CONF.replace("view_dim", "view_dimm"))
    _, error = fails(["train", *FAST, "--conf", str(conf), "--out", str(tmp_path / "out")], capsys)
    assert f"{conf}: entry 'CampusNav-v0': env_kwargs: unknown key 'view_dimm' of CampusNavEnv" in error
    assert "(did you mean 'view_dim'?)" in error
    assert not (tmp_path / "out").exists()


def test_invalid_yaml_names_the_file_and_the_line(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    conf = tmp_path / "broken.yml"
    conf.write_text("CampusNav-v0:\n  n_timesteps: 200\n  policy: [MultiInputPolicy\n  buffer_size: 500\n")
    _, error = fails(["train", *FAST, "--conf", str(conf), "--out", str(tmp_path / "out")], capsys)
    assert f"--conf: {conf}: not valid YAML (line " in error and "Traceback" not in error
    schedule = tmp_path / "closures.yml"
    schedule.write_text("closures:\n  - {at: 100, close: [[14, 15]]\n")
    _, error = fails(["train", *FAST, "--closures", str(schedule), "--out", str(tmp_path / "out")], capsys)
    assert f"--closures: {schedule}" in error and "line 3" in error and "Traceback" not in error
    assert not (tmp_path / "out").exists()


@pytest.mark.parametrize(
    ("line", "message"),
    [
        ('learning_rate: "fast"', 'learning_rate: expected a positive number or a schedule (a callable of the '
         "remaining progress), got 'fast'"),
        ("learning_rate: 1e-3", "learning_rate: expected a positive number or a schedule (a callable of the "
         "remaining progress), got '1e-3' (YAML reads 1e-3 as a string: write 0.001 or !!float 1e-3)"),
        ("batch_size: -64", "batch_size: expected a positive integer, got -64"),
        ("buffer_size: 5.0e+2", "buffer_size: expected a positive integer, got 500.0 (write 500)"),
        ("gamma: 1.5", "gamma: expected a number in [0, 1], got 1.5"),
        ("gradient_steps: 0", "gradient_steps: expected a positive integer, or -1 (as many as env steps), got 0"),
        ('blocked_action_target: "yes"', "blocked_action_target: expected true or false, got 'yes' (write true, "
         "without quotes)"),
        ("device: cuad", "device: unknown device 'cuad' (devices: auto, cpu, cuda, mps or cuda:N; did you mean "
         "'cuda'?)"),
    ],
)  # fmt: skip
def test_a_bad_hyperparameter_value_names_the_file_entry_and_key_before_any_work(
    tmp_path: Path, line: str, message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    conf = tmp_path / "mine.yml"
    key = line.split(":")[0]
    # The good entry with this key's line replaced by (or added as) the bad one
    lines = [text for text in GOOD_CONF.splitlines() if not text.strip().startswith(f"{key}:")]
    conf.write_text("\n".join([*lines, f"  {line}"]) + "\n")
    out = tmp_path / "out"
    _, error = fails(["train", *FAST, "--conf", str(conf), "--out", str(out)], capsys)
    assert error == f"dcqn-campusnav train: error: --conf: {conf}: entry 'CampusNav-v0': {message}\n"
    assert not out.exists()  # not even tb/: refused before any training


def test_a_non_positive_n_timesteps_is_refused(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    conf = tmp_path / "mine.yml"
    conf.write_text(GOOD_CONF.replace("n_timesteps: 200", "n_timesteps: 0"))
    _, error = fails(["train", *FAST, "--conf", str(conf), "--out", str(tmp_path / "out")], capsys)
    assert error == f"dcqn-campusnav train: error: --conf: {conf}: entry 'CampusNav-v0': n_timesteps: expected a " + (
        "positive integer, got 0\n"
    )


@pytest.mark.parametrize(
    ("line", "why"),
    [
        ("normalize: true", "VecNormalize: the route evaluation, the route memory and evaluate read the env's own"),
        ("frame_stack: 4", "the route evaluation gives the model one observation at a time"),
        ("env_wrapper: gymnasium.wrappers.TimeLimit", "evaluate, readapt and the route evaluation build the env as"),
        ("vec_env_wrapper: stable_baselines3.common.vec_env.VecCheckNan", "the route evaluation, the route memory"),
        ("monitor_kwargs: {info_keywords: [is_success]}", "no Monitor log is kept"),
        ("seed: 3", "--seed sets it; remove it"),
        ("tensorboard_log: tb", "each run logs to tb/ in its own folder"),
    ],
)
def test_an_entry_key_dcqn_campusnav_does_not_apply_is_refused_naming_it(
    tmp_path: Path, line: str, why: str, capsys: pytest.CaptureFixture[str]
) -> None:
    conf = tmp_path / "mine.yml"
    conf.write_text(f"{GOOD_CONF}  {line}\n")
    key = line.split(":")[0]
    for argv in (
        ["train", *FAST, "--out", str(tmp_path / "out")],
        ["draw", *FAST, "--picture", str(tmp_path / "a.png")],
    ):
        _, error = fails([*argv, "--conf", str(conf)], capsys)
        assert error.startswith(
            f"dcqn-campusnav {argv[0]}: error: --conf: {conf}: entry 'CampusNav-v0': {key}: not applied by "
            f"dcqn-campusnav ({why}"
        ), error
        assert error.count("\n") == 1
    assert not (tmp_path / "out").exists() and not (tmp_path / "a.png").exists()


# ------------------------------------------------------------------------------------------------ output paths
def test_a_feature_cache_that_is_a_file_is_refused_before_any_work(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]
) -> None:
    a_file = tmp_path / "cache.txt"
    a_file.write_text("mine\n")
    monkeypatch.setenv("CAMPUSNAV_CACHE", str(a_file))
    out = tmp_path / "out"
    for argv in (["train", *FAST, "--out", str(out)], ["draw", *FAST, "--picture", str(tmp_path / "map.png")]):
        _, error = fails(argv, capsys)
        assert error.endswith(f": error: $CAMPUSNAV_CACHE {a_file}: is a file, not a folder\n")
    assert not out.exists() and not (tmp_path / "map.png").exists() and a_file.read_text() == "mine\n"


def test_an_output_folder_that_cannot_be_made_is_refused_before_any_work(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    import tempfile

    try:  # /proc refuses new folders, even to root (whom os.access lets write anywhere)
        os.rmdir(tempfile.mkdtemp(dir="/proc"))
        pytest.skip("this system lets /proc hold new folders")
    except OSError:
        pass
    _, error = fails(["train", *FAST, "--out", "/proc/nope"], capsys)
    assert error.startswith("dcqn-campusnav train: error: --out /proc/nope: cannot write in /proc (")
    assert error.count("\n") == 1


@pytest.mark.parametrize("name", ["map.jpg", "map.PDF", "map"])
def test_a_picture_that_is_not_png_is_refused_naming_the_suffix(
    tmp_path: Path, name: str, capsys: pytest.CaptureFixture[str]
) -> None:
    picture = tmp_path / name
    _, error = fails(["draw", *FAST, "--picture", str(picture)], capsys)
    assert f"--picture {picture}: pictures are written as PNG; give a name ending in .png" in error
    assert not picture.exists()


def test_resnet50_without_weights_is_refused_unless_random_features_are_asked_for(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    out = tmp_path / "out"
    _, error = fails(["train", "--encoder", "resnet50", "--out", str(out)], capsys)
    assert "--encoder resnet50: needs --encoder-weights FILE" in error and "--encoder-random-init" in error
    _, error = fails(["train", *FAST, "--encoder-random-init", "--out", str(out)], capsys)
    assert "--encoder-random-init: only for --encoder resnet50 (the encoder is pixels)" in error
    assert not out.exists()


def test_random_resnet50_features_asked_for_are_built_quietly_and_saved_with_the_settings() -> None:
    import warnings

    from campusnav_env.features.encoders import ResNet50Encoder
    from sb3_dcqn.campusnav.settings import EnvSettings

    settings = EnvSettings("CampusNav-v0", encoder="resnet50", encoder_random_init=True)
    assert settings.make_kwargs()["view_build"].encoder_kwargs == {"random_init": True}
    assert EnvSettings.from_json(settings.to_json()) == settings and "(random init)" in settings.describe()
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # asked for: no "features are not pretrained" warning
        encoder = ResNet50Encoder(**settings.make_kwargs()["view_build"].encoder_kwargs)
    assert "random-seed0" in encoder.name
    with pytest.raises(ValueError, match="random_init=True and a weights_path"):
        ResNet50Encoder("resnet50.pth", random_init=True)


def test_an_output_folder_under_a_file_is_refused_before_training(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    a_file = tmp_path / "notes.txt"
    a_file.write_text("mine\n")
    _, error = fails(["train", *FAST, "--out", str(a_file / "run")], capsys)
    assert f"--out {a_file / 'run'}: is inside {a_file}, a file, not a folder" in error
    _, error = fails(["demo", *FAST, "--out", str(a_file)], capsys)
    assert f"--out {a_file}: is a file, not a folder" in error
    assert a_file.read_text() == "mine\n"


def test_a_picture_path_under_a_file_is_refused_before_the_scores(
    tmp_path: Path, saved_model: bytes, capsys: pytest.CaptureFixture[str]
) -> None:
    model = tmp_path / "model.zip"
    model.write_bytes(saved_model)
    a_file = tmp_path / "notes.txt"
    a_file.write_text("mine\n")
    printed, error = fails(["evaluate", str(model), *FAST, "--picture", str(a_file / "routes.png")], capsys)
    assert f"--picture {a_file / 'routes.png'}: is inside {a_file}, a file, not a folder" in error
    assert "| all |" not in printed  # checked before the model was evaluated
    _, error = fails(["draw", *FAST, "--picture", str(tmp_path)], capsys)
    assert f"--picture {tmp_path}: is a folder" in error
    assert a_file.read_text() == "mine\n" and model.read_bytes() == saved_model


def test_readapt_to_an_output_folder_under_a_file_keeps_the_model(
    tmp_path: Path, saved_model: bytes, capsys: pytest.CaptureFixture[str]
) -> None:
    model = tmp_path / "model.zip"
    model.write_bytes(saved_model)
    a_file = tmp_path / "notes.txt"
    a_file.write_text("mine\n")
    _, error = fails(["readapt", str(model), "--close", "14", "15", "--out", str(a_file / "again")], capsys)
    assert f"--out {a_file / 'again'}: is inside {a_file}" in error
    assert model.read_bytes() == saved_model and a_file.read_text() == "mine\n"


# ------------------------------------------------------------------------------------------------ model files
@pytest.mark.parametrize("command", ["evaluate", "readapt", "draw"])
def test_a_truncated_model_is_not_a_readable_model_file(
    tmp_path: Path, saved_model: bytes, command: str, capsys: pytest.CaptureFixture[str]
) -> None:
    model = tmp_path / "model.zip"
    model.write_bytes(saved_model[: len(saved_model) // 2])
    before = files_under(tmp_path)
    argv = {
        "evaluate": ["evaluate", str(model)],
        "readapt": ["readapt", str(model), "--close", "14", "15"],
        "draw": ["draw", "--model", str(model), "--picture", str(tmp_path / "map.png")],
    }[command]
    _, error = fails([*argv, *FAST], capsys)
    assert f"{model}: not a readable model file" in error
    assert "pass the --env" not in error  # not a matter of env flags
    assert files_under(tmp_path) == before


def test_a_file_that_is_not_a_model_zip_says_so(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    readme = tmp_path / "README.md"
    readme.write_text("# notes\n")
    for argv in (
        ["evaluate", str(readme)],
        ["draw", "--model", str(readme)],
        ["readapt", str(readme), "--close-random", "1"],
    ):
        _, error = fails([*argv, *FAST], capsys)
        assert f"{readme}: not a model zip (a model is a .zip file written by DCQN.save)" in error
        assert "not found" not in error and error.count("\n") == 1
    _, error = fails(["evaluate", str(tmp_path), *FAST], capsys)
    assert f"{tmp_path}: is a folder, not a model file" in error


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "--seed", "-1"], "argument --seed: expected an integer from 0 to 2**32 - 1, got '-1'"),
        (["train", "-n", "-5"], "argument --timesteps/-n/--n-timesteps: expected a positive integer, got '-5'"),
        (
            ["train", "--timesteps", "-5"],
            "argument --timesteps/-n/--n-timesteps: expected a positive integer, got '-5'",
        ),
        (["demo", "--eval-freq", "0"], "argument --eval-freq: expected a positive integer, got '0'"),
        (["evaluate"], "the following arguments are required: MODEL.zip"),
        (["--seed", "x"], "argument --seed: expected an integer from 0 to 2**32 - 1, got 'x'"),
    ],
)
def test_a_bad_flag_value_is_one_line_without_the_usage(
    argv: list[str], message: str, capsys: pytest.CaptureFixture[str]
) -> None:
    _, error = fails(argv, capsys)
    command = "demo" if argv[0].startswith("-") else argv[0]
    assert (
        error == f"dcqn-campusnav {command}: error: {message} ('dcqn-campusnav {command} --help' lists the options)\n"
    )


@pytest.fixture(scope="module")
def small_map(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A 4 x 4 street grid in metres, its far corner a library: 13 intersections once simplified (the bends go)."""
    import networkx as nx

    graph = nx.Graph()
    for k in range(16):
        graph.add_node(str(k), x=100.0 * (k % 4), y=100.0 * (k // 4))
        if k % 4 < 3:
            graph.add_edge(str(k), str(k + 1))
        if k < 12:
            graph.add_edge(str(k), str(k + 4))
    graph.nodes["15"]["name"] = "Library"
    path = tmp_path_factory.mktemp("maps") / "small.graphml"
    nx.write_graphml(graph, path)
    return path


def test_a_goal_not_on_ones_own_map_is_refused_with_the_subcommands_own_flag(
    tmp_path: Path, small_map: Path, saved_model: bytes, capsys: pytest.CaptureFixture[str]
) -> None:
    _, error = fails(["draw", *FAST, "--map", str(small_map), "--picture", str(tmp_path / "map.png")], capsys)
    assert f"--map {small_map}: goal 'Dreese Lab' (the default of CampusNav-v0) is not a landmark" in error
    assert "pass --goal with a landmark name" in error and "--goals" not in error
    model = tmp_path / "model.zip"
    model.write_bytes(saved_model)
    _, error = fails(["evaluate", str(model), *FAST, "--map", str(small_map)], capsys)
    assert "is not a landmark of the map" in error and "pass --goals" not in error
    assert "use a model trained on this map ('dcqn-campusnav train --map FILE --goals" in error
    _, error = fails(["train", *FAST, "--map", str(small_map), "--out", str(tmp_path / "out")], capsys)
    assert "pass --goals with landmark names" in error


def test_a_map_with_fewer_views_than_the_entrys_view_dim_is_drawn_with_the_view_dim_it_allows(
    tmp_path: Path, small_map: Path
) -> None:
    # 13 intersections: fewer views than the shipped entry's view_dim (64) projects them to; the env fits it, said once
    picture = tmp_path / "map.png"
    argv = ["draw", *FAST, "--map", str(small_map), "--goal", "Library", "--picture", str(picture)]
    with pytest.warns(UserWarning, match=r"view_dim 64 is more than this map's \d+ views") as said:
        run(build_parser().parse_args(argv))
    assert picture.is_file()
    assert sum("view_dim 64" in str(warning.message) for warning in said) == 1


# ------------------------------------------------------------------------------------------------ closures
def test_a_closure_that_cuts_the_goal_off_gives_the_command_lines_advice(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, error = fails(["draw", *FAST, "--close", *DEAD_END, "--picture", str(tmp_path / "map.png")], capsys)
    assert f"--close {DEAD_END[0]} {DEAD_END[1]}: closing road (0, 11) would cut protected node 81" in error
    assert "force=True" not in error and "dcqn-campusnav roads NODE" in error
    _, error = fails(["train", *FAST, "--close", *DEAD_END, "--out", str(tmp_path / "out")], capsys)
    assert "--close: " in error and "would cut protected node 81" in error and "force=True" not in error
    assert not (tmp_path / "map.png").exists() and not (tmp_path / "out").exists()


# ------------------------------------------------------------------------------------------------ help
def test_help_is_plain_text_and_imports_neither_torch_nor_campusnav() -> None:
    code = (
        "import contextlib, io, sys\n"
        "from sb3_dcqn.campusnav import cli\n"
        "texts = io.StringIO()\n"
        "for argv in ([], *([command] for command in sys.argv[1:])):\n"
        "    with contextlib.redirect_stdout(texts), contextlib.suppress(SystemExit):\n"
        "        cli.build_parser().parse_args([*argv, '--help'])\n"
        "heavy = [m for m in ('torch', 'stable_baselines3', 'campusnav_env', 'gymnasium') if m in sys.modules]\n"
        "print(repr(heavy)); print(texts.getvalue())\n"
    )
    commands = ["demo", "train", "evaluate", "readapt", "draw", "roads"]
    done = subprocess.run(
        [sys.executable, "-c", code, *commands], capture_output=True, text=True, timeout=120, check=True
    )
    heavy, _, texts = done.stdout.partition("\n")
    assert heavy == "[]"
    for markup in REST_MARKUP:
        assert markup not in texts, markup
    assert "Subcommands ('dcqn-campusnav SUBCOMMAND --help'" in texts
    for command in commands:
        assert f"usage: dcqn-campusnav {command}" in texts


def test_help_names_every_encoder_and_the_recovery_thresholds() -> None:
    from campusnav_env.features.encoders import ENCODER_NAMES
    from campusnav_env.recovery import DEFAULT_SPL_THRESHOLD, DEFAULT_SUCCESS_THRESHOLD

    for name in ENCODER_NAMES:
        assert name in campusnav_cli.ENCODER_HELP, name
    assert (
        f"success rate >= {DEFAULT_SUCCESS_THRESHOLD} and SPL >= {DEFAULT_SPL_THRESHOLD}" in campusnav_cli.DESCRIPTION
    )


def test_an_unknown_encoder_is_refused_with_the_choices(capsys: pytest.CaptureFixture[str]) -> None:
    _, error = fails(["draw", "--encoder", "jpeg"], capsys)
    assert "--encoder: invalid choice: 'jpeg' (choose from efficientnet-lite0, resnet50, pixels, thumbnail)" in error


# ------------------------------------------------------------------------------------------------ pictures
def test_pictures_are_titled_with_start_goal_closures_and_score(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    drawn: list[dict[str, Any]] = []

    def record(graph: Any, **kwargs: Any) -> np.ndarray:
        drawn.append(kwargs)
        return np.zeros((64, 64, 3), dtype=np.uint8)

    monkeypatch.setattr(pictures, "draw_map", record)
    run(build_parser().parse_args(["draw", *FAST, "--close", "14", "15", "--start", "3", "--node-ids",
                                   "--picture", str(tmp_path / "map.png")]))  # fmt: skip
    (kwargs,) = drawn
    assert kwargs["node_ids"] is True
    assert kwargs["title"] == "from node 3 to Dreese Lab (node 81); closed: 14-15"


def test_route_title_names_the_route_and_its_score() -> None:
    from campusnav_env import CampusNavEnv
    from campusnav_env.features.view_build import ViewBuild
    from campusnav_env.figures import pick_route
    from campusnav_env.rendering.street_view import RenderSettings
    from campusnav_env.route_evaluation import evaluate_routes

    nav = CampusNavEnv(
        encoder="pixels", view_build=ViewBuild(render_settings=RenderSettings(width=64, height=48), progress=False)
    )
    nav.close_road(14, 15)
    report = evaluate_routes(nav, lambda observations: np.zeros(len(observations["heading"]), dtype=np.int64))
    route = pick_route(report.routes, goal="Dreese Lab", start=3, heading=0)
    assert route is not None
    title = pictures.route_title(nav, "Dreese Lab", route, 3, report)
    outcome = f"{route.steps} steps" if route.success else "fails"
    score = report.for_goal("Dreese Lab")
    assert title == (
        f"from node 3 facing N to Dreese Lab (node 81); closed: 14-15; learned route: {outcome} (shortest "
        f"{route.shortest}); all routes to Dreese Lab: success {score.success_rate:.3f}, SPL {score.spl:.3f}"
    )


def test_draw_writes_node_ids_and_a_title(tmp_path: Path) -> None:
    # Renders for real: needs draw_map's node_ids= and title= (campusnav_env.rendering.map_view)
    picture = tmp_path / "map.png"
    summary = run(build_parser().parse_args(["draw", *FAST, "--node-ids", "--picture", str(picture)]))
    assert picture.is_file() and summary["picture"] == str(picture)


# ------------------------------------------------------------------------------------------------ misspelt names
@pytest.mark.parametrize("command", ["train", "demo"])
def test_a_misspelt_goal_on_the_built_in_map_names_the_nearest_landmark_before_any_view(
    tmp_path: Path, command: str, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    cache = tmp_path / "cache"
    monkeypatch.setenv("CAMPUSNAV_CACHE", str(cache))  # an empty cache: nothing may be rendered into it
    out = tmp_path / "out"
    _, error = fails([command, *FAST, "--goals", "Dreese Labs", "--out", str(out)], capsys)
    assert error.count("\n") == 1 and "Traceback" not in error
    assert error.startswith(f"dcqn-campusnav {command}: error: goal 'Dreese Labs' (--goals) is not a landmark of ")
    assert "(nearest: Dreese Lab; its named nodes: Bookstore, " in error
    assert error.endswith("; pass --goals with landmark names or node ids 0..100\n")
    assert not out.exists() and files_under(tmp_path) == {}  # no folder, no view
    _, error = fails([command, *FAST, "--goals", "500", "--out", str(out)], capsys)
    assert "goal node 500 (--goals) is not on the map 'campus-n101-seed0' (node ids 0..100)" in error


def test_a_misspelt_goal_of_evaluate_or_draw_names_the_nearest_goal(
    tmp_path: Path, capsys: pytest.CaptureFixture[str]
) -> None:
    _, error = fails(["draw", *FAST, "--env", "CampusNavMulti-v0", "--goal", "cinema", "--picture",
                      str(tmp_path / "map.png")], capsys)  # fmt: skip
    assert "--goal 'cinema': not a goal of this env (nearest: Cinema; goals: Dreese Lab, Town house, Cinema" in error
    assert not (tmp_path / "map.png").exists()


@pytest.mark.parametrize("command", [["train"], ["roads", "5"]])
def test_a_road_to_a_node_off_the_map_says_the_node_is_not_on_it(
    tmp_path: Path, command: list[str], capsys: pytest.CaptureFixture[str]
) -> None:
    flags = [*FAST, "--out", str(tmp_path / "out")] if command[0] == "train" else []  # roads takes no view flags
    _, error = fails([*command, *flags, "--close", "5", "500"], capsys)
    assert "node 500 is not on the map 'campus-n101-seed0' (node ids 0..100)" in error
    assert "no road between" not in error and "dcqn-campusnav roads NODE" in error
    assert files_under(tmp_path) == {}


@pytest.mark.parametrize(
    ("argv", "message"),
    [
        (["train", "--timestpes", "5"], "unrecognized arguments: --timestpes 5 (did you mean --timesteps?)"),
        (["evaluate", "m.zip", "--node-idz"], "unrecognized arguments: --node-idz (did you mean --node-ids?)"),
        (["--n-closurs=3"], "unrecognized arguments: --n-closurs=3 (did you mean --n-closures?)"),
        (["roads", "5", "--frobnicate"], "unrecognized arguments: --frobnicate"),
    ],
)
def test_a_misspelt_flag_gets_did_you_mean_and_its_subcommands_help(
    argv: list[str], message: str, tmp_path: Path, capsys: pytest.CaptureFixture[str], monkeypatch: pytest.MonkeyPatch
) -> None:
    monkeypatch.chdir(tmp_path)  # a flag taken after all would write its run here, not into the repository
    _, error = fails(argv, capsys)
    command = "demo" if argv[0].startswith("-") else argv[0]
    assert error == (
        f"dcqn-campusnav {command}: error: {message} ('dcqn-campusnav {command} --help' lists the options)\n"
    )


def test_a_misspelt_subcommand_gets_did_you_mean(capsys: pytest.CaptureFixture[str]) -> None:
    _, error = fails(["trian", "--timesteps", "5"], capsys)
    assert error == (
        "dcqn-campusnav: error: no subcommand 'trian' (did you mean train?); choose from demo, train, evaluate, "
        "readapt, draw, roads ('dcqn-campusnav --help' lists the options)\n"
    )


def test_draw_without_a_model_never_encodes_views_with_the_cnn(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from campusnav_env.features import encoders

    def no_cnn(*args: object, **kwargs: object) -> None:
        raise AssertionError("the CNN was built")

    monkeypatch.setitem(encoders._ENCODERS, "efficientnet-lite0", no_cnn)
    picture = tmp_path / "ids.png"
    run(build_parser().parse_args(["draw", "--node-ids", "--picture", str(picture)]))  # the default encoder
    assert picture.is_file()


# ------------------------------------------------------------------------------------------------ refusals as values
def test_the_command_line_says_the_maps_refusals_in_its_flags_from_their_values() -> None:
    from campusnav_env.maps.navigation import RoadClosureError
    from campusnav_env.maps.osm import CoordinatesError
    from campusnav_env.maps.refusals import Setting
    from sb3_dcqn.campusnav.errors import said

    error = CoordinatesError(
        "{given} says x/y are degrees", "if they are metres, pass {fix}",
        given=Setting("coords", "lonlat"), fix=Setting("coords", "projected"), where="town.graphml",
    )  # fmt: skip
    assert (
        str(error) == "town.graphml: coords='lonlat' says x/y are degrees; if they are metres, pass coords='projected'"
    )
    assert (
        said(error)
        == "town.graphml: --map-coords lonlat says x/y are degrees; if they are metres, pass --map-coords projected"
    )
    closure = RoadClosureError((0, 11), 81, ["Dreese Lab"], 1)
    assert (closure.road, closure.node, closure.n_cut, closure.fix) == ((0, 11), 81, 1, Setting("force", True))
    assert str(closure).endswith("that reach it now; pass force=True to close it anyway")
    assert said(closure).endswith("that reach it now; close another road instead")  # no flag forces a closure


# ------------------------------------------------------------------------------------------------ routes
def test_a_failed_route_says_why_it_stopped() -> None:
    from campusnav_env import CampusNavEnv
    from campusnav_env.figures import route_text
    from campusnav_env.maps.compass import ACTION_NAMES
    from campusnav_env.rendering.street_view import RenderSettings
    from campusnav_env.route_evaluation import evaluate_routes

    nav = CampusNavEnv(
        encoder="pixels", view_build={"render_settings": RenderSettings(width=64, height=48), "progress": False}
    )
    back = ACTION_NAMES.index("back")

    def always(action: int) -> Any:
        return lambda observations: np.full(len(observations["heading"]), action, dtype=np.int64)

    routes = evaluate_routes(nav, always(ACTION_NAMES.index("forward")), max_steps=500).routes
    assert {route.ended for route in routes} <= {"goal", "blocked", "loop", "step limit"}
    stuck = next(route for route in routes if route.ended == "blocked")
    assert f"(stuck at node {stuck.nodes[-1]}" in route_text(nav.graph, stuck)
    turning = [route for route in evaluate_routes(nav, always(back)).routes if not route.success]
    assert {route.ended for route in turning} == {"blocked", "loop"}  # no road behind, or back and forth on one
    looping = next(route for route in turning if route.ended == "loop")
    assert len(looping.nodes) == 3 and looping.nodes[0] == looping.nodes[2]
    assert f"goes round a loop (back at node {looping.nodes[0]} facing the same way)" in route_text(nav.graph, looping)
    limited = evaluate_routes(nav, always(back), max_steps=1).routes  # one move: no loop yet where it moved
    assert {route.ended for route in limited} == {"goal", "blocked", "step limit"}
    failed = next(route for route in limited if route.ended == "step limit")
    assert "(the step limit reached; scored as 1 steps)" in route_text(nav.graph, failed)
