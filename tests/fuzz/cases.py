"""The table of bad inputs, one builder per case: ``builder(tmp, run) -> Case``.

``tmp`` is an empty directory the case may fill; ``run`` is a complete one-episode run directory inside it
(``tmp/run``: run.json, episodes/*.mcap, labels/). Every file that exists when the builder returns is hashed
and must be byte-identical after the command.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from pathlib import Path

from harness import Case

MODEL = ["--model", "scripted", "--scenarios", "P.1", "--seeds", "1", "--quiet"]
CASES: dict[str, Callable[[Path, Path], Case]] = {}


def case(surface: str):
    def add(builder: Callable[[Path, Path], Case]) -> Callable[[Path, Path], Case]:
        CASES[f"{surface}: {builder.__name__}"] = builder
        return builder
    return add


def scenario_json(scenario_id: str = "P.1", **changes) -> dict:
    from vladrivebench._scenarios.spec import resolve_scenarios

    data = resolve_scenarios(scenario_id)[0].to_json()
    data.update(changes)
    return data


def episode_log(run: Path) -> Path:
    return sorted((run / "episodes").glob("*.mcap"))[0]


# -- configuration files ---------------------------------------------------------------------------
@case("config")
def config_not_utf8(tmp, run):
    (tmp / "c.toml").write_bytes(b'model = "scr\xff\xfeipted"\n')
    return Case("", ["run", "--config", str(tmp / "c.toml"), "--out", str(tmp / "o")], mentions=("c.toml",))


@case("config")
def config_not_toml(tmp, run):
    (tmp / "c.toml").write_text("model = [\n")
    return Case("", ["run", "--config", str(tmp / "c.toml"), "--out", str(tmp / "o")], mentions=("c.toml",))


@case("config")
def config_wrong_type(tmp, run):
    (tmp / "c.toml").write_text('seeds = "three"\n')
    return Case("", ["run", *MODEL[:4], "--config", str(tmp / "c.toml"), "--out", str(tmp / "o")],
                mentions=("seeds",))


@case("config")
def config_unknown_key(tmp, run):
    (tmp / "c.toml").write_text('modle = "scripted"\n')
    return Case("", ["run", "--config", str(tmp / "c.toml"), "--out", str(tmp / "o")], mentions=("modle",))


@case("config")
def config_is_directory(tmp, run):
    (tmp / "c.toml").mkdir()
    return Case("", ["run", *MODEL, "--config", str(tmp / "c.toml"), "--out", str(tmp / "o")])


@case("config")
def config_bad_option_table(tmp, run):
    (tmp / "c.toml").write_text("[model_options]\nalpha = 2.0\n")
    return Case("", ["run", *MODEL, "--config", str(tmp / "c.toml"), "--out", str(tmp / "o")], mentions=("alpha",))


# -- scenario files --------------------------------------------------------------------------------
@case("scenario")
def scenario_toml_not_utf8(tmp, run):
    (tmp / "s.toml").write_bytes(b'id = "X\xff.1"\n')
    return Case("", ["scenarios", str(tmp / "s.toml")], mentions=("s.toml",))


@case("scenario")
def scenario_toml_not_utf8_in_run(tmp, run):
    (tmp / "s.toml").write_bytes(b'\xef\xbb\xbftitle = "\xc3\x28"\n')
    return Case("", ["run", "--model", "scripted", "--scenarios", str(tmp / "s.toml"), "--seeds", "1",
                     "--out", str(tmp / "o")], mentions=("s.toml",))


@case("scenario")
def scenario_json_not_utf8(tmp, run):
    (tmp / "s.json").write_bytes(b'{"id": "\xff"}')
    return Case("", ["scenarios", str(tmp / "s.json")], mentions=("s.json",))


@case("scenario")
def scenario_json_list(tmp, run):
    (tmp / "s.json").write_text("[1, 2]")
    return Case("", ["scenarios", str(tmp / "s.json")], mentions=("s.json",))


@case("scenario")
def scenario_yaml(tmp, run):
    (tmp / "s.yaml").write_text("id: X.1\n")
    return Case("", ["scenarios", str(tmp / "s.yaml")], mentions=(".toml", ".json"))


@case("scenario")
def scenario_missing_file(tmp, run):
    return Case("", ["scenarios", str(tmp / "nope.toml")], mentions=("nope.toml",))


@case("scenario")
def scenario_actor_beyond_road(tmp, run):
    data = scenario_json("P.1", id="X.far")
    data["actors"][0]["position"] = 5000.0
    (tmp / "far.json").write_text(json.dumps(data))
    return Case("", ["scenarios", str(tmp / "far.json")], mentions=("far.json", "position"))


@case("scenario")
def scenario_same_id_twice(tmp, run):
    data = scenario_json("P.1", id="X.dup")
    (tmp / "a.json").write_text(json.dumps(data))
    data["title"] = "another"
    (tmp / "b.json").write_text(json.dumps(data))
    return Case("", ["scenarios", f"{tmp / 'a.json'},{tmp / 'b.json'}"], mentions=("a.json", "b.json"))


@case("scenario")
def scenario_redefines_suite_id(tmp, run):
    data = scenario_json("P.1", title="mine, not the suite's")
    (tmp / "mine.json").write_text(json.dumps(data))
    return Case("", ["scenarios", f"P.1,{tmp / 'mine.json'}"], mentions=("mine.json", "P.1"))


@case("scenario")
def scenario_unknown_field(tmp, run):
    data = scenario_json("P.1", id="X.u", colour="blue")
    (tmp / "u.json").write_text(json.dumps(data))
    return Case("", ["scenarios", str(tmp / "u.json")], mentions=("colour",))


# -- condition files -------------------------------------------------------------------------------
def _intervene(tmp, *extra):
    return ["intervene", "--model", "scripted", "--route", "E.1", "--seeds", "1", "--out", str(tmp / "o"),
            "--quiet", *extra]


@case("conditions")
def conditions_toml_not_utf8(tmp, run):
    (tmp / "k.toml").write_bytes(b'[conditions.x]\nsentence = "\xff"\n')
    return Case("", _intervene(tmp, "--condition-file", str(tmp / "k.toml")), mentions=("k.toml",))


@case("conditions")
def conditions_json_wrong_shape(tmp, run):
    (tmp / "k.json").write_text('{"conditions": [1]}')
    return Case("", _intervene(tmp, "--condition-file", str(tmp / "k.json")), mentions=("k.json",))


@case("conditions")
def conditions_empty_list(tmp, run):
    return Case("", _intervene(tmp, "--conditions", ""), mentions=("--conditions",))


@case("conditions")
def conditions_unknown(tmp, run):
    return Case("", _intervene(tmp, "--conditions", "nosuch"), mentions=("nosuch",))


@case("conditions")
def checkpoints_beyond_episode(tmp, run):
    return Case("", _intervene(tmp, "--mode", "closed-loop", "--checkpoints", "1000"), mentions=("--checkpoints",))


@case("conditions")
def checkpoints_not_numbers(tmp, run):
    return Case("", _intervene(tmp, "--mode", "closed-loop", "--checkpoints", "a,b"), mentions=("--checkpoints",))


# -- label JSONL -----------------------------------------------------------------------------------
def _texts(tmp: Path, body: bytes) -> Path:
    path = tmp / "texts.jsonl"
    path.write_bytes(body)
    return path


@case("labels")
def texts_out_is_input(tmp, run):
    path = _texts(tmp, b'{"id": 1, "text": "Stop for the pedestrian."}\n')
    return Case("", ["label", "--texts", str(path), "--out", str(path), "--quiet"], mentions=("texts.jsonl",))


@case("labels")
def texts_out_is_episode_log(tmp, run):
    path = _texts(tmp, b'{"id": 1, "text": "Stop for the pedestrian."}\n')
    return Case("", ["label", "--texts", str(path), "--out", str(episode_log(run)), "--quiet"], mentions=(".mcap",))


@case("labels")
def texts_out_in_run_directory(tmp, run):
    path = _texts(tmp, b'{"id": 1, "text": "Stop for the pedestrian."}\n')
    return Case("", ["label", "--texts", str(path), "--out", str(run / "episodes" / "x.jsonl"), "--quiet"],
                mentions=(str(run),))


@case("labels")
def texts_not_utf8(tmp, run):
    path = _texts(tmp, b'{"id": 1, "text": "\xff"}\n')
    return Case("", ["label", "--texts", str(path), "--out", str(tmp / "o.jsonl")], mentions=("texts.jsonl",))


@case("labels")
def texts_line_without_id(tmp, run):
    path = _texts(tmp, b'{"id": 1, "text": "Stop."}\n{"text": "Go."}\n')
    return Case("", ["label", "--texts", str(path), "--out", str(tmp / "o.jsonl")], mentions=("texts.jsonl:2", "id"))


@case("labels")
def texts_not_json(tmp, run):
    path = _texts(tmp, b'{"id": 1, "text": "Stop."\n')
    return Case("", ["label", "--texts", str(path), "--out", str(tmp / "o.jsonl")], mentions=("texts.jsonl:1",))


@case("labels")
def texts_out_under_a_file(tmp, run):
    path = _texts(tmp, b'{"id": 1, "text": "Stop."}\n')
    (tmp / "f").write_text("x")
    return Case("", ["label", "--texts", str(path), "--out", str(tmp / "f" / "o.jsonl")], mentions=("--out",))


# -- run manifest ----------------------------------------------------------------------------------
@case("manifest")
def manifest_list(tmp, run):
    (run / "run.json").write_text("[1, 2, 3]\n")
    return Case("", ["run", *MODEL, "--out", str(run)], mentions=("run.json",))


@case("manifest")
def manifest_config_not_object(tmp, run):
    (run / "run.json").write_text('{"format": 1, "config": 5, "versions": "x"}\n')
    return Case("", ["run", *MODEL, "--out", str(run)], mentions=("run.json",))


@case("manifest")
def manifest_not_json(tmp, run):
    (run / "run.json").write_text('{"format": 1, ')
    return Case("", ["run", *MODEL, "--out", str(run)], mentions=("run.json",))


@case("manifest")
def manifest_not_utf8(tmp, run):
    (run / "run.json").write_bytes(b'{"format": "\xff"}')
    return Case("", ["run", *MODEL, "--out", str(run)], mentions=("run.json",))


@case("manifest")
def manifest_other_configuration(tmp, run):
    return Case("", ["run", *MODEL, "--model-opt", "alpha=0.9", "--out", str(run)], mentions=("alpha",))


# -- episode logs ----------------------------------------------------------------------------------
@case("logs")
def log_truncated_strict(tmp, run):
    log = episode_log(run)
    log.write_bytes(log.read_bytes()[: log.stat().st_size // 2])
    return Case("", ["metrics", str(run), "--strict"], mentions=(log.name,))


@case("logs")
def log_byte_flipped_strict(tmp, run):
    log = episode_log(run)
    data = bytearray(log.read_bytes())
    data[len(data) // 3] ^= 0x5A
    log.write_bytes(bytes(data))
    return Case("", ["metrics", str(run), "--strict"], mentions=(log.name,))


@case("logs")
def log_not_mcap_strict(tmp, run):
    episode_log(run).write_text("# not a log\n")
    return Case("", ["metrics", str(run), "--strict"], mentions=(episode_log(run).name,))


@case("logs")
def log_directory_missing(tmp, run):
    return Case("", ["metrics", str(tmp / "nowhere")], mentions=("nowhere",))


@case("logs")
def log_directory_empty(tmp, run):
    (tmp / "empty").mkdir()
    return Case("", ["metrics", str(tmp / "empty")], mentions=("empty",))


# -- output paths ----------------------------------------------------------------------------------
@case("paths")
def report_out_is_episode_log(tmp, run):
    return Case("", ["report", str(run), "--format", "md", "--out", str(episode_log(run))], mentions=(".mcap",))


@case("paths")
def report_out_is_manifest(tmp, run):
    return Case("", ["report", str(run), "--format", "md", "--out", str(run / "run.json")], mentions=("run.json",))


@case("paths")
def report_out_in_episodes(tmp, run):
    return Case("", ["report", str(run), "--format", "md", "--out", str(run / "episodes" / "r.md")],
                mentions=("episodes",))


@case("paths")
def report_out_is_label_store(tmp, run):
    store = sorted((run / "labels").glob("*.jsonl"))[0]
    return Case("", ["report", str(run), "--format", "md", "--out", str(store)], mentions=(store.name,))


@case("paths")
def report_out_under_a_file(tmp, run):
    (tmp / "f").write_text("x")
    return Case("", ["report", str(run), "--format", "md", "--out", str(tmp / "f" / "r.md")], mentions=("--out",))


@case("paths")
def report_out_is_directory(tmp, run):
    (tmp / "d").mkdir()
    return Case("", ["report", str(run), "--format", "md", "--out", str(tmp / "d")], mentions=("--out",))


@case("paths")
def run_out_under_a_file(tmp, run):
    (tmp / "f").write_text("x")
    return Case("", ["run", *MODEL, "--out", str(tmp / "f" / "o")], mentions=("--out",))


@case("paths")
def run_out_is_a_file(tmp, run):
    (tmp / "f").write_text("x")
    return Case("", ["run", *MODEL, "--out", str(tmp / "f")], mentions=("--out",))


@case("paths")
def run_episodes_is_a_file(tmp, run):
    (tmp / "o").mkdir()
    (tmp / "o" / "episodes").write_text("x")
    return Case("", ["run", *MODEL, "--out", str(tmp / "o")], mentions=("episodes",))


@case("paths")
def run_out_is_episode_log(tmp, run):
    return Case("", ["run", *MODEL, "--out", str(episode_log(run))], mentions=("--out",))


@case("paths")
def run_out_inside_run(tmp, run):
    return Case("", ["run", *MODEL, "--out", str(run / "episodes" / "nested")], mentions=(str(run),))


@case("paths")
def intervene_out_is_a_run(tmp, run):
    return Case("", _intervene(tmp)[:-3] + ["--out", str(run), "--quiet"], mentions=(str(run),))


# -- names and numbers -----------------------------------------------------------------------------
@case("numbers")
def seeds_huge(tmp, run):
    return Case("", ["run", *MODEL[:4], "--seeds", "1000000000000", "--out", str(tmp / "o")], mentions=("--seeds",))


@case("numbers")
def seeds_zero(tmp, run):
    return Case("", ["run", *MODEL[:4], "--seeds", "0", "--out", str(tmp / "o")], mentions=("--seeds",))


@case("numbers")
def seeds_not_a_number(tmp, run):
    return Case("", ["run", *MODEL[:4], "--seeds", "three", "--out", str(tmp / "o")], mentions=("--seeds",))


@case("numbers")
def seed_offset_negative(tmp, run):
    return Case("", ["run", *MODEL, "--seed-offset", "-1", "--out", str(tmp / "o")], mentions=("--seed-offset",))


@case("numbers")
def intervene_seeds_huge(tmp, run):
    args = _intervene(tmp)
    args[args.index("--seeds") + 1] = "1000000000000"
    return Case("", args, mentions=("--seeds",))


@case("numbers")
def model_option_out_of_range(tmp, run):
    return Case("", ["run", *MODEL, "--model-opt", "alpha=2", "--out", str(tmp / "o")], mentions=("alpha",))


@case("numbers")
def model_option_unknown(tmp, run):
    return Case("", ["run", *MODEL, "--model-opt", "alhpa=0.5", "--out", str(tmp / "o")], mentions=("alhpa",))


@case("numbers")
def controller_max_speed_negative(tmp, run):
    return Case("", ["run", *MODEL, "--controller-opt", "max_speed=-1", "--out", str(tmp / "o")],
                mentions=("max_speed",))


@case("numbers")
def controller_speed_window_text(tmp, run):
    return Case("", ["run", *MODEL, "--controller-opt", "speed_window=abc", "--out", str(tmp / "o")],
                mentions=("speed_window",))


@case("numbers")
def mpc_horizon_zero(tmp, run):
    return Case("", ["run", *MODEL, "--controller", "mpc", "--controller-opt", "horizon_steps=0",
                     "--out", str(tmp / "o")], mentions=("horizon_steps",))


@case("numbers")
def sim_option_unknown(tmp, run):
    return Case("", ["run", *MODEL, "--sim-opt", "gravity=3", "--out", str(tmp / "o")], mentions=("gravity",))


@case("numbers")
def workers_zero(tmp, run):
    return Case("", ["run", *MODEL, "--workers", "0", "--out", str(tmp / "o")], mentions=("workers",))


@case("numbers")
def sequential_with_workers(tmp, run):
    return Case("", ["run", *MODEL, "--executor", "sequential", "--workers", "2", "--out", str(tmp / "o")],
                mentions=("--workers",))


@case("names")
def model_unknown(tmp, run):
    return Case("", ["run", "--model", "scriptd", *MODEL[2:], "--out", str(tmp / "o")], mentions=("scriptd",))


@case("names")
def model_disabled(tmp, run):
    return Case("", ["run", *MODEL, "--out", str(tmp / "o")], env={"VDB_DISABLE_PLUGINS": "scripted"},
                mentions=("disabled", "VDB_DISABLE_PLUGINS"))


@case("names")
def executor_unknown(tmp, run):
    return Case("", ["run", *MODEL, "--executor", "nosuch", "--out", str(tmp / "o")], mentions=("nosuch",))


@case("names")
def controller_unknown(tmp, run):
    return Case("", ["run", *MODEL, "--controller", "lqr", "--out", str(tmp / "o")], mentions=("lqr",))


@case("names")
def scenario_unknown(tmp, run):
    return Case("", ["run", "--model", "scripted", "--scenarios", "Q.9", "--seeds", "1", "--out", str(tmp / "o")],
                mentions=("Q.9",))


@case("names")
def scenarios_empty(tmp, run):
    return Case("", ["run", "--model", "scripted", "--scenarios", ",", "--seeds", "1", "--out", str(tmp / "o")],
                mentions=("scenarios",))


@case("names")
def labeler_unknown(tmp, run):
    return Case("", ["label", str(run), "--labeler", "nosuch"], mentions=("nosuch",))


@case("names")
def option_without_value(tmp, run):
    return Case("", ["run", *MODEL, "--model-opt", "alpha", "--out", str(tmp / "o")], mentions=("alpha",))


@case("names")
def ray_unreachable_address(tmp, run):
    return Case("", ["run", *MODEL, "--executor", "ray", "--address", "127.0.0.1:1", "--out", str(tmp / "o")],
                mentions=("127.0.0.1:1",))


# -- plugins ---------------------------------------------------------------------------------------
def fake_distribution(tmp: Path, dist: str, plugin: str, source: str) -> str:
    """A plugin module plus a ``*.dist-info`` declaring its entry point, in ``tmp/site``."""
    site = tmp / "site"
    info = site / f"{dist.replace('-', '_')}-0.1.dist-info"
    info.mkdir(parents=True, exist_ok=True)
    (info / "METADATA").write_text(f"Metadata-Version: 2.1\nName: {dist}\nVersion: 0.1\n")
    (info / "entry_points.txt").write_text(f"[vladrivebench]\n{plugin} = {plugin.replace('-', '_')}\n")
    (site / f"{plugin.replace('-', '_')}.py").write_text(source)
    return str(site)


@case("plugins")
def plugin_exits_at_import_strict(tmp, run):
    site = fake_distribution(tmp, "vdb-exits", "exits", "import sys\nsys.exit(3)\n")
    return Case("", ["--strict-plugins", "list-plugins"], sys_path=(site,), mentions=("exits", "vdb-exits"))


@case("plugins")
def plugin_raises_at_import_strict(tmp, run):
    site = fake_distribution(tmp, "vdb-raises", "raises", "raise RuntimeError('boom')\n")
    return Case("", ["--strict-plugins", "list-plugins"], sys_path=(site,), mentions=("raises", "vdb-raises"))


@case("plugins")
def plugin_exits_in_register_commands_strict(tmp, run):
    source = "import sys\nimport vladrivebench\n\n@vladrivebench.hookimpl\ndef register_commands(cli):\n    sys.exit(4)\n"
    site = fake_distribution(tmp, "vdb-cmd", "cmdexit", source)
    return Case("", ["--strict-plugins", "list-plugins"], sys_path=(site,), mentions=("cmdexit",))
