"""Scenario files: bundled ones load, dump/load round-trips, overrides, and errors a user can act on."""

from __future__ import annotations

import math
import tempfile
import tomllib
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from config.loader import ScenarioError, dump_scenario, load_scenario, parse_overrides, scenario_from_dict
from config.scenario import Scenario
from tests.conftest import SCENARIOS

BUNDLED = sorted(SCENARIOS.glob("*.toml"))


def write(tmp_path: Path, text: str, name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(text, encoding="utf-8")
    return path


def error_of(path, overrides=()) -> ScenarioError:
    with pytest.raises(ScenarioError) as info:
        load_scenario(path, overrides)
    return info.value


# --- bundled scenarios ---------------------------------------------------------------------------


def test_the_bundled_scenarios_exist():
    assert {p.name for p in BUNDLED} >= {"paper-fig4.toml", "paper-fig5.toml", "quick.toml"}


@pytest.mark.parametrize("path", BUNDLED, ids=lambda p: p.name)
def test_bundled_scenario_loads_and_round_trips(path, tmp_path):
    sc = load_scenario(path)
    text = dump_scenario(sc)
    back = load_scenario(write(tmp_path, text, "run.toml"))
    assert back == sc
    data = tomllib.loads(text)
    assert (data["n"], data["dt"]) == (sc.n, sc.dt)
    assert [tuple(e) for e in data["edges"]] == sc.edges()


@pytest.mark.parametrize("path", BUNDLED, ids=lambda p: p.name)
def test_every_bundled_value_is_commented(path):
    for lineno, line in enumerate(path.read_text().splitlines(), start=1):
        if "=" in line and not line.lstrip().startswith("#"):
            assert "#" in line, f"{path.name}:{lineno}: value without a comment"


def test_paper_scenarios_follow_the_paper():
    fig4 = load_scenario(SCENARIOS / "paper-fig4.toml")
    fig5 = load_scenario(SCENARIOS / "paper-fig5.toml")
    assert (fig4.n, fig4.dt, fig4.noise.sigma_v, fig4.load.mass, fig4.load.inertia) == (10, 0.01, 0.3, 50.0, 86.89)
    assert (fig4.load.width, fig4.load.height, fig4.seed, fig4.duration) == (4.0, 2.2, 1, 120.0)
    assert fig4.dynamics.algorithm == "sequential" and fig4.duration <= 200.0  # the paper's Algorithm 1 in 200 s
    assert fig4.graph.topology == "line" and fig5.graph.topology == "complete"
    assert fig4.load.com_offset != (0.0, 0.0)
    differing = {k for k in Scenario.model_fields if getattr(fig4, k) != getattr(fig5, k)}
    # and the kinematic consensus gains, which must shrink with the degree (0.3 diverges on the complete graph)
    assert differing == {"name", "graph", "estimator"}
    assert fig5.estimator.omega_eps * fig5.n < 2 and fig5.estimator.centroid_eps * fig5.n < 2
    quick = load_scenario(SCENARIOS / "quick.toml")
    assert (quick.n, quick.noise.sigma_v, quick.duration) == (5, 0.1, 20.0)


# --- run.toml ------------------------------------------------------------------------------------


def test_run_toml_with_recording_table_loads(tmp_path):
    sc = load_scenario(SCENARIOS / "paper-fig5.toml")
    text = dump_scenario(sc) + '\n[recording]\nengine = "inproc"\nstarted = "2026-01-01T00:00:00"\n'
    assert load_scenario(write(tmp_path, text)) == sc


def test_a_record_key_in_the_recording_table_is_an_error(tmp_path):
    text = dump_scenario(load_scenario(SCENARIOS / "quick.toml")) + "\n[recording]\nrig = \"lab 2\"\nevery_ticks = 1\n"
    err = error_of(write(tmp_path, text))
    assert err.field == "recording.every_ticks" and "did you mean [record]" in err.message
    assert err.line == len(text.splitlines())


def test_run_toml_with_wrong_edges_is_rejected(tmp_path):
    sc = load_scenario(SCENARIOS / "quick.toml")
    lines = dump_scenario(sc).splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith("edges"))
    lines[start] = "edges = [[0, 1], [1, 2], [2, 3], [0, 4]]"  # a line graph would end with [3, 4]
    err = error_of(write(tmp_path, "\n".join(lines)))
    assert (err.field, err.line) == ("edges", start + 1)
    assert "disagrees with the graph" in err.message


def test_edges_order_and_direction_do_not_matter(tmp_path):
    text = 'n = 3\nedges = [[2, 1], [1, 0]]\n[graph]\ntopology = "line"\n'
    assert load_scenario(write(tmp_path, text)).edges() == [(0, 1), (1, 2)]


# --- overrides -----------------------------------------------------------------------------------


def test_parse_overrides_types_and_nesting():
    got = parse_overrides(
        ["load.mass=60", "noise.sigma_v=0.1", "a.b.c=true", "initial.v_c=[1, 2]", 'name="x y"', "graph.topology=ring",
         "--set seed=4", "link.loss.model = bernoulli"]
    )  # fmt: skip
    assert got == {
        "load": {"mass": 60},
        "noise": {"sigma_v": 0.1},
        "a": {"b": {"c": True}},
        "initial": {"v_c": [1, 2]},
        "name": "x y",
        "graph": {"topology": "ring"},
        "seed": 4,
        "link": {"loss": {"model": "bernoulli"}},
    }


def test_overrides_apply_on_top_of_the_file():
    sc = load_scenario(
        SCENARIOS / "paper-fig4.toml",
        ["load.mass=60", "graph.topology=complete", "initial.v_c=[0.5, -1]", "link.loss.model=bernoulli",
         "link.loss.p=0.25", "n=6", "name=my run"],
    )  # fmt: skip
    assert sc.load.mass == 60.0 and isinstance(sc.load.mass, float)
    assert sc.load.inertia == 86.89  # untouched siblings keep their file values
    assert sc.graph.topology == "complete" and sc.n == 6 and len(sc.edges()) == 15
    assert sc.initial.v_c == (0.5, -1.0)
    assert (sc.link.loss.model, sc.link.loss.p) == ("bernoulli", 0.25)
    assert sc.name == "my run"


# --- errors --------------------------------------------------------------------------------------

BAD_FILE = """\
name = "bad"
n = 4

[load]
# the CoM offset spans two lines
com_offset = [0.1,
   0.2]
mass = -3
"""


def test_out_of_range_names_file_line_field_and_value(tmp_path):
    path = write(tmp_path, BAD_FILE, "paper-fig4.toml")
    err = error_of(path)
    assert (err.file, err.line, err.field) == (str(path), 8, "load.mass")
    assert str(err) == f"{path}:8: load.mass: Input should be greater than 0 (got -3)"


def test_wrong_type(tmp_path):
    err = error_of(write(tmp_path, 'name = "x"\n\nn = "ten"\n'))
    assert (err.line, err.field) == (3, "n")
    assert "valid integer" in err.message and '"ten"' in err.message


def test_wrong_type_inside_multiline_array(tmp_path):
    err = error_of(write(tmp_path, BAD_FILE.replace("   0.2]", '   "a"]').replace("-3", "3")))
    assert (err.line, err.field) == (6, "load.com_offset[1]")


def test_all_problems_are_reported_at_once(tmp_path):
    err = error_of(write(tmp_path, BAD_FILE.replace("   0.2]", '   "a"]')))
    assert {e.field for e in err.errors} == {"load.mass", "load.com_offset[1]"}
    assert len(str(err).splitlines()) == 2


def test_unknown_key_suggests_the_right_one(tmp_path):
    err = error_of(write(tmp_path, "[load]\nmas = 3\n\n[noise]\nsigma = 0.1\n"))
    by_field = {e.field: e for e in err.errors}
    assert by_field["load.mas"].line == 2
    assert by_field["load.mas"].message == "unknown key (did you mean 'mass'?)"
    assert by_field["noise.sigma"].line == 5 and "did you mean 'sigma_v'?" in by_field["noise.sigma"].message


def test_unknown_top_level_table(tmp_path):
    err = error_of(write(tmp_path, "n = 3\n\n[lods]\nmass = 3\n"))
    assert (err.line, err.field) == (3, "lods") and "did you mean 'load'?" in err.message


def test_literal_choice(tmp_path):
    err = error_of(write(tmp_path, '[graph]\ntopology = "star"\n'))
    assert (err.line, err.field) == (2, "graph.topology")
    assert "'line'" in err.message and '"star"' in err.message


def test_toml_syntax_error_has_line(tmp_path):
    err = error_of(write(tmp_path, "n = 3\n[load]\nmass = = 3\n"))
    assert err.line == 3 and "TOML syntax error" in err.message and err.field == ""
    assert str(err).startswith(f"{tmp_path / 's.toml'}:3: TOML syntax error")


def test_explicit_edges_out_of_range(tmp_path):
    text = 'n = 3\n\n[graph]\ntopology = "explicit"\nedges = [[0, 1], [1, 3]]\n'
    err = error_of(write(tmp_path, text))
    assert (err.line, err.field) == (5, "graph.edges")
    assert "[1, 3]" in err.message and "0..2" in err.message


def test_disconnected_graph(tmp_path):
    text = 'n = 4\n\n[graph]\ntopology = "explicit"\nedges = [[0, 1], [2, 3]]\n'
    err = error_of(write(tmp_path, text))
    assert (err.line, err.field) == (5, "graph.edges") and "connected" in err.message


def test_explicit_contact_count(tmp_path):
    text = 'n = 3\n\n[contacts]\nlayout = "explicit"\npoints = [[0, 1], [1, 0]]\n'
    err = error_of(write(tmp_path, text))
    assert (err.line, err.field) == (5, "contacts.points") and "(got 2)" in err.message


def test_model_level_error_inside_a_table(tmp_path):
    text = '[load]\nshape = "polygon"\nvertices = [[0, 0], [0, 1], [1, 0]]\n'  # clockwise
    err = error_of(write(tmp_path, text))
    assert (err.line, err.field) == (3, "load.vertices") and "counter-clockwise" in err.message


def test_missing_key_points_at_its_table(tmp_path):
    err = error_of(write(tmp_path, 'n = 3\n\n[load]\nshape = "polygon"\n'))
    assert (err.line, err.field) == (3, "load")


def test_dotted_and_inline_keys_are_located(tmp_path):
    err = error_of(write(tmp_path, "n = 3\nload.mass = -1\n"))
    assert (err.line, err.field) == (2, "load.mass")
    err = error_of(write(tmp_path, 'n = 3\ntext = """\n[load]\nmass = 1\n"""\nload = { mass = -1 }\n'))
    lines = {e.field: e.line for e in err.errors}
    assert lines == {"load.mass": 6, "text": 2}  # not the fake [load] table inside the string
    err = error_of(write(tmp_path, 'n = 3\n\nload = { width = 1.0, mass = -1 }\n'))
    assert (err.line, err.field) == (3, "load.mass")


def test_non_finite_values_are_rejected(tmp_path):
    err = error_of(write(tmp_path, "[initial]\nangle = nan\n"))
    assert (err.line, err.field) == (2, "initial.angle") and "finite" in err.message


@pytest.mark.parametrize(
    ("override", "label", "field"),
    [
        ("load.mass=-3", "--set load.mass=-3", "load.mass"),
        ("seed=1.5", "--set seed=1.5", "seed"),
        ("load.mas=3", "--set load.mas=3", "load.mas"),
        ("n.x=1", "--set n.x=1", "n"),
        ("nokey", "--set nokey", ""),
        ("=3", "--set 3", ""),
        ("a..b=3", "--set a..b=3", ""),
        ("graph.edges=[[0, 1], [2, 3]]", "--set graph.edges=[[0, 1], [2, 3]]", "graph.edges"),
    ],
)
def test_bad_override_names_the_override(override, label, field):
    overrides = ["graph.topology=explicit", override] if "edges" in override else [override]
    err = error_of(SCENARIOS / "quick.toml", overrides)
    assert (err.file, err.line, err.field) == (label, None, field)
    assert str(err).startswith(label + ":")


def test_missing_file():
    err = error_of(SCENARIOS / "no-such.toml")
    assert err.line is None and "cannot read" in err.message


def test_scenario_from_dict_errors_name_the_source():
    with pytest.raises(ScenarioError) as info:
        scenario_from_dict({"load": {"mass": 0}}, source="api")
    assert str(info.value) == "api: load.mass: Input should be greater than 0 (got 0)"


# --- random valid scenarios round-trip -----------------------------------------------------------

finite = st.floats(-1e6, 1e6, allow_nan=False, allow_infinity=False)
positive = st.floats(1e-3, 1e3)
unit = st.floats(0.0, 1.0)


@st.composite
def scenarios(draw) -> Scenario:
    n = draw(st.integers(2, 12))
    data: dict = {
        "name": draw(st.text(max_size=20)),
        "n": n,
        "dt": (dt := draw(positive)),
        "duration": dt * draw(st.floats(1.0, 1e5)),  # at least one tick
        "seed": draw(st.integers(0, 2**63)),
        "mode": draw(st.sampled_from(["lockstep", "realtime"])),
    }
    inner = st.floats(-1.0, 1.0)  # the CoM lies inside the outline: a fraction of a box inside it
    load: dict = {"mass": draw(positive)}
    if draw(st.booleans()):
        k = draw(st.integers(3, 8))
        load |= {"shape": "polygon", "vertices": [
            [math.cos(2 * math.pi * i / k) * 2, math.sin(2 * math.pi * i / k)] for i in range(k)
        ], "com_offset": [0.25 * draw(inner), 0.25 * draw(inner)]}  # fmt: skip
    else:
        load |= {"width": (w := draw(positive)), "height": (h := draw(positive))}
        load["com_offset"] = [0.5 * w * draw(inner), 0.5 * h * draw(inner)]
    if draw(st.booleans()):
        load["inertia"] = draw(positive)
    data["load"] = load
    if draw(st.booleans()):
        pts = draw(st.lists(st.tuples(finite, finite), min_size=n, max_size=n, unique=True))
        data["contacts"] = {"layout": "explicit", "points": [list(p) for p in pts]}
    else:
        data["contacts"] = {"start": draw(st.floats(0.0, 0.999))}
    data["noise"] = {"sigma_v": draw(st.floats(0.0, 5.0))}
    topology = draw(st.sampled_from(["line", "ring", "complete", "explicit"]))
    data["graph"] = {"topology": topology}
    if topology == "explicit":
        tree = [[draw(st.integers(0, i - 1)), i] for i in range(1, n)]  # a random spanning tree
        data["graph"]["edges"] = tree
    data["link"] = {
        "delay_ticks": draw(st.integers(0, 10)),
        "jitter_s": draw(st.floats(0.0, 1.0)),
        "loss": {"model": draw(st.sampled_from(["none", "bernoulli", "gilbert_elliott"])), "p": draw(unit)},
    }
    data["initial"] = {"angle": draw(finite), "omega": draw(finite), "v_c": [draw(finite), draw(finite)]}
    return scenario_from_dict(data)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(sc=scenarios())
def test_random_scenarios_round_trip(sc):
    text = dump_scenario(sc)
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "run.toml"
        path.write_text(text, encoding="utf-8")
        assert load_scenario(path) == sc
    assert dump_scenario(scenario_from_dict(tomllib.loads(text))) == text


def test_scenario_by_bundled_name_run_dir_or_path(tmp_path, monkeypatch):
    """`coload run paper-fig4` means the bundled file; a run directory means its run.toml."""
    from config.loader import bundled_scenario_names

    monkeypatch.chdir(tmp_path)  # bare names must not depend on the working directory
    by_name = load_scenario("paper-fig4")
    assert by_name == load_scenario(SCENARIOS / "paper-fig4.toml")
    assert load_scenario("paper-fig4.toml") == by_name
    run_dir = tmp_path / "a-run"
    run_dir.mkdir()
    (run_dir / "run.toml").write_text((SCENARIOS / "quick.toml").read_text(encoding="utf-8"), encoding="utf-8")
    assert load_scenario(run_dir).name == load_scenario("quick").name
    assert {"paper-fig4", "paper-fig5", "paper-fig9", "quick"} <= set(bundled_scenario_names())
    with pytest.raises(ScenarioError, match="bundled scenarios: .*paper-fig4"):
        load_scenario("no-such-scenario")


def test_encoding_a_byte_order_mark_is_fine_other_encodings_are_located(tmp_path):
    path = tmp_path / "bom.toml"
    path.write_bytes(b"\xef\xbb\xbf" + b'name = "bom"\nn = 5\n')
    assert load_scenario(path).name == "bom"
    path = tmp_path / "latin1.toml"
    path.write_bytes(b'n = 5\nname = "r\xe9glage"\n')
    err = error_of(path)
    assert err.line == 2 and "not UTF-8" in err.message
