"""Token files (sumo_scendiff.tokens.file): TOML/JSON parity, frames, defaults, one-line errors."""
import json
import math
from pathlib import Path

import numpy as np
import pytest

from sumo_scendiff.core.geometry import Window
from sumo_scendiff.tokens.encoding import (
    FEATURE_SLICES,
    PRESENCE_SLICE,
    agent_tokens_from_dicts,
)
from sumo_scendiff.tokens.file import (
    TokenFileError,
    TokenSpec,
    load_tokens,
    parse_tokens,
)

EXAMPLES = Path(__file__).resolve().parents[1] / "examples" / "tokens"

TOML = """\
frame = "window"
p_mask = 0.25
[[agents]]
x = 12.0
y = -1.6
heading = 0.0
length = 10.5
width = 2.5
speed = 8.0
final_speed = 0.0
[[agents]]
x = -20
y = 1.6
"""
AGENTS = ({"x": 12.0, "y": -1.6, "heading": 0.0, "length": 10.5, "width": 2.5, "speed": 8.0,
           "final_speed": 0.0}, {"x": -20.0, "y": 1.6})


def _write(tmp_path, name, text):
    p = tmp_path / name
    p.write_text(text if isinstance(text, str) else json.dumps(text), encoding="utf-8")
    return p


def test_toml_and_json_give_the_same_spec(tmp_path):
    t = load_tokens(_write(tmp_path, "a.toml", TOML))
    j = load_tokens(_write(tmp_path, "a.json", {"frame": "window", "p_mask": 0.25,
                                                "agents": [dict(a) for a in AGENTS]}))
    assert isinstance(t, TokenSpec)
    assert t.agents == j.agents == AGENTS
    assert (t.frame, t.p_mask, j.frame, j.p_mask) == ("window", 0.25, "window", 0.25)
    assert t.source == str(tmp_path / "a.toml") and j.source == str(tmp_path / "a.json")
    assert isinstance(t.agents[1]["x"], float)
    assert parse_tokens({"agents": [{"speed": 3, "heading": None}]}, "sweep.toml").agents == ({"speed": 3.0},)


def test_default_frame_and_p_mask(tmp_path):
    spec = parse_tokens({"agents": [{"speed": 3.0}]}, "s")
    assert (spec.frame, spec.p_mask) == ("window", 0.5)
    assert parse_tokens({}, "s").p_mask == 1.0
    only_global = load_tokens(_write(tmp_path, "g.toml", "p_mask = 0.3\n"))
    assert (only_global.p_mask, only_global.agents, only_global.for_window(Window(0, 0))) == (0.3, (), [])
    assert parse_tokens({"agents": []}, "s").p_mask == 1.0
    assert parse_tokens({"p_mask": 0, "agents": [{"speed": 1}]}, "s").p_mask == 0.0


def test_world_frame_to_rotated_window():
    spec = parse_tokens({"frame": "world", "agents": [
        {"x": 100.0, "y": 210.0, "heading": math.pi / 2, "length": 4.5, "width": 1.8, "speed": 5.0,
         "final_speed": 6.0, "heading_to_final": 0.3},
        {"x": 90.0, "y": 200.0, "heading": math.pi},
        {"heading": 0.0}, {"speed": 2.0}]}, "w.toml")
    got = spec.for_window(Window(100.0, 200.0, math.pi / 2))
    assert got[0]["x"] == pytest.approx(10.0, abs=1e-9) and got[0]["y"] == pytest.approx(0.0, abs=1e-9)
    assert got[0]["heading"] == pytest.approx(0.0, abs=1e-12)
    assert {k: got[0][k] for k in ("length", "width", "speed", "final_speed", "heading_to_final")} == \
        {"length": 4.5, "width": 1.8, "speed": 5.0, "final_speed": 6.0, "heading_to_final": 0.3}
    assert got[1]["x"] == pytest.approx(0.0, abs=1e-9) and got[1]["y"] == pytest.approx(10.0)
    assert got[1]["heading"] == pytest.approx(math.pi / 2)
    assert got[2] == {"heading": pytest.approx(-math.pi / 2)} and got[3] == {"speed": 2.0}
    assert spec.agents[0]["x"] == 100.0  # the spec itself is not modified
    # window frame: unchanged, returned as copies
    w = parse_tokens({"agents": [{"x": 5.0, "y": 1.0, "heading": 0.2}]}, "w")
    out = w.for_window(Window(100.0, 200.0, 1.0))
    assert out == [{"x": 5.0, "y": 1.0, "heading": 0.2}] and out[0] is not w.agents[0]


def test_for_window_encodes_to_tokens():
    spec = parse_tokens({"frame": "world", "agents": [
        {"x": 100.0, "y": 210.0, "heading": math.pi / 2, "speed": 8.0},
        {"length": 12.0, "width": 2.5}]}, "w")
    tok = agent_tokens_from_dicts(spec.for_window(Window(100.0, 200.0, math.pi / 2)))
    assert tok.shape == (2, 170) and tok.dtype == np.float32
    assert tok[0, FEATURE_SLICES["x"]].argmax() == 38  # floor((10 + 50) / 1.5625)
    assert tok[0, FEATURE_SLICES["y"]].argmax() == 32
    np.testing.assert_allclose(tok[0, FEATURE_SLICES["heading"]], [1.0, 0.0], atol=1e-7)
    assert tok[0, FEATURE_SLICES["speed"]].argmax() == 4
    assert tok[:, PRESENCE_SLICE].tolist() == [[1, 1, 1, 0, 0, 1, 0, 0], [0, 0, 0, 1, 1, 0, 0, 0]]


@pytest.mark.parametrize("agent,window,msg", [
    ({"x": 100.0, "y": 260.5}, Window(100.0, 200.0, math.pi / 2), r"agents\[0\]: world position \(100, 260.5\)"),
    ({"x": 151.0, "y": 200.0}, Window(100.0, 200.0, 0.0), "outside the window"),
    ({"x": 0.0, "y": 0.0}, Window(1000.0, 0.0, 0.0), r"\(-1000.00, 0.00\) m in the window frame"),
])
def test_world_agent_outside_window(agent, window, msg):
    spec = parse_tokens({"frame": "world", "agents": [agent]}, "w.toml")
    with pytest.raises(TokenFileError, match=msg) as e:
        spec.for_window(window)
    assert str(e.value).startswith("w.toml: agents[0]: ") and "\n" not in str(e.value)


def test_window_agent_outside_small_window():
    spec = parse_tokens({"agents": [{"speed": 1.0}, {"x": 30.0, "y": 0.0}]}, "w.json")
    assert spec.for_window(Window(0, 0))[1] == {"x": 30.0, "y": 0.0}
    with pytest.raises(TokenFileError, match=r"^w.json: agents\[1\]: position is \(30.00, 0.00\)"):
        spec.for_window(Window(0, 0, 0.0, 50.0))


ERRORS = [
    ("t.toml", "p_mask = 0.5\n[[agents]]\nspeed = 1.0\n[[agents]]\nspeed = -3.0\n",
     "agents[1]: token feature 'speed' must be >= 0 m/s, got -3.0"),
    ("t.toml", "pmask = 0.5\n", "unknown key 'pmask' (expected frame, p_mask, agents)"),
    ("t.toml", "p_mask = 0.5\nframe = 'window'\nagents = [\n", "not valid TOML ("),
    ("t.json", '{"agents": [}', "not valid JSON ("),
    ("t.json", {"agents": {"x": 1.0, "y": 2.0}}, "'agents' must be a list of tables"),
    ("t.json", {"agents": [3]}, "'agents' must be a list of tables: agents[0] is 3"),
    ("t.json", {"p_mask": "a lot"}, "p_mask must be a number in [0, 1], got 'a lot'"),
    ("t.json", {"p_mask": True}, "p_mask must be a number in [0, 1], got True"),
    ("t.toml", "p_mask = 1.5\n", "p_mask must be a number in [0, 1], got 1.5"),
    ("t.toml", "p_mask = nan\n", "p_mask must be a number in [0, 1], got nan"),
    ("t.toml", 'frame = "scene"\n', "frame must be \"window\" or \"world\", got 'scene'"),
    ("t.json", [1, 2], "top level must be a table, got list"),
    ("t.json", {"agents": [{"spead": 3}]}, "agents[0]: unknown token feature 'spead'"),
    ("t.json", {"agents": [{"speed": "fast"}]}, "agents[0]: token feature 'speed' must be numeric, got 'fast'"),
    ("t.json", {"agents": [{"speed": False}]}, "agents[0]: token feature 'speed' must be numeric, got False"),
    ("t.json", {"agents": [{"speed": [1, 2]}]}, "agents[0]: token feature 'speed' must be a single number, got [1, 2]"),
    ("t.json", {"agents": [{"x": 1.0}]}, "agents[0]: features x and y (position) must be given together"),
    ("t.json", {"agents": [{"length": 4.0, "width": 0}]}, "agents[0]: token feature 'width' must be > 0 metres, got 0.0"),
    ("t.json", {"agents": [{"x": 51.0, "y": 0}]}, "agents[0]: token feature 'x' = 51.0 m is outside the 100 m window"),
    ("t.json", {"agents": [{}]}, "agents[0]: no token features (give at least one of x, y,"),
    ("t.json", {"frame": "world", "agents": [{"x": "1", "y": 2.0}]},
     "agents[0]: token feature 'x' must be a finite number (world metres), got '1'"),
    ("t.json", {"frame": "world", "agents": [{"x": 1e4, "y": 2.0, "speed": -1}]},
     "agents[0]: token feature 'speed' must be >= 0 m/s, got -1.0"),
    ("t.json", {"frame": "world", "agents": [{"y": 2.0}]}, "features x and y (position) must be given together"),
    ("t.toml", "[[agents]]\nheading = inf\n", "agents[0]: token feature 'heading' must be finite"),
    ("t.yaml", "p_mask: 0.5\n", "unknown token file type '.yaml' (expected .toml, .json or .xosc)"),
    ("t", "p_mask = 0.5\n", "unknown token file type '(none)'"),
]


@pytest.mark.parametrize("name,content,expected", ERRORS)
def test_errors_are_one_line_and_start_with_the_path(tmp_path, name, content, expected):
    path = _write(tmp_path, name, content)
    with pytest.raises(TokenFileError) as e:
        load_tokens(path)
    msg = str(e.value)
    assert isinstance(e.value, ValueError) and "\n" not in msg
    assert msg.startswith(f"{path}: "), msg
    assert expected in msg, msg


def test_missing_file_and_directory(tmp_path):
    with pytest.raises(TokenFileError) as e:
        load_tokens(tmp_path / "nope.toml")
    assert str(e.value) == f"{tmp_path / 'nope.toml'}: no such file"
    (tmp_path / "d.json").mkdir()
    with pytest.raises(TokenFileError, match=r"d\.json: is a directory"):
        load_tokens(tmp_path / "d.json")
    with pytest.raises(TokenFileError, match=r"^relative\.toml: no such file$"):
        load_tokens("relative.toml")
    with pytest.raises(TokenFileError, match=r"^sweep\.toml: unknown key 'agent'"):
        parse_tokens({"agent": []}, "sweep.toml")


def test_example_files_load():
    truck = load_tokens(EXAMPLES / "truck_stopping.toml")
    assert (truck.frame, truck.p_mask) == ("window", 0.6)
    assert truck.agents == ({"x": 12.0, "y": 0.0, "heading": 0.0, "length": 10.5, "width": 2.5,
                             "speed": 8.0, "final_speed": 0.0},)
    cross = load_tokens(EXAMPLES / "cross_traffic.json")
    assert (cross.frame, cross.p_mask) == ("window", 0.8)
    assert [(a["x"], a["y"], a["heading"], a["speed"]) for a in cross.agents] == \
        [(3.0, -20.0, math.pi / 2, 10.0), (-3.0, -20.0, math.pi / 2, 10.0)]
    for spec in (truck, cross):
        assert agent_tokens_from_dicts(spec.for_window(Window(0.0, 0.0, 0.7))).shape == (len(spec.agents), 170)


def test_every_example_file_loads():
    files = sorted(EXAMPLES.iterdir())
    assert len(files) >= 4
    for f in files:
        spec = load_tokens(f)
        assert spec.agents and all(isinstance(a, dict) for a in spec.agents)


def test_a_users_terms_become_features_and_references():
    spec = parse_tokens({"agents": [
        {"ahead": 15, "lane_offset": -1, "vclass": "truck", "speed": 8, "manoeuvre": "stop"},
        {"edge": "E1", "pos": 30, "manoeuvre": "turn_left"},
        {"edge": "E1", "lane": 2, "pos": 0.5, "vclass": "motorcycle", "manoeuvre": "turn_right"},
        {"x": 1, "y": 2, "manoeuvre": "straight", "vclass": "car"}]}, "t.toml")
    a, b, c, d = spec.agents
    assert a == {"length": 10.5, "width": 2.5, "speed": 8.0, "final_speed": 0.0, "ahead": 15.0, "lane_offset": -1,
                 "vclass": "truck"}
    assert b == {"heading_to_final": 0.4, "edge": "E1", "lane": 0, "pos": 30.0}       # CCW = left
    assert c["heading_to_final"] == -0.4 and (c["length"], c["width"], c["lane"]) == (2.2, 0.9, 2)
    assert d == {"x": 1.0, "y": 2.0, "length": 4.6, "width": 1.8, "heading_to_final": 0.0, "vclass": "passenger"}
    # the class stays with the token for the seeding (an alias as the model's class name); the model never sees it
    np.testing.assert_array_equal(agent_tokens_from_dicts([d]),
                                  agent_tokens_from_dicts([{k: v for k, v in d.items() if k != "vclass"}]))
    # references pass the window frame unchanged: generation resolves them on the network
    assert spec.for_window(Window(500.0, 500.0, 1.0))[1] == b


def test_a_token_may_name_a_vtype_the_model_never_sees(tmp_path):
    """``vtype`` names one of the scenario's vTypes (checked, and its size given, where the scenario
    is known: tests/test_fleet.py); the model's encoding leaves it out."""
    spec = load_tokens(_write(tmp_path, "v.toml", '[[agents]]\nvtype = "bus_articulated"\n'
                                                  '[[agents]]\nx = 3.0\ny = 1.0\nvtype = "car"\nlength = 4.0\nwidth = 1.7\n'))
    assert spec.agents == ({"vtype": "bus_articulated"}, {"x": 3.0, "y": 1.0, "length": 4.0, "width": 1.7, "vtype": "car"})
    assert spec.for_window(Window(0.0, 0.0, 0.0))[1]["vtype"] == "car"
    np.testing.assert_array_equal(agent_tokens_from_dicts([spec.agents[1]]),
                                  agent_tokens_from_dicts([{k: v for k, v in spec.agents[1].items() if k != "vtype"}]))


def test_vehicle_classes_are_the_fleets_sizes():
    from sumo_scendiff.core.scene import VEHICLE_CLASSES
    from sumo_scendiff.data.demand import VEHICLE_MIX
    from sumo_scendiff.tokens.file import VCLASS_SIZES
    fleet = {vid: (length, width) for vid, _, _, length, width, *_ in VEHICLE_MIX}
    assert set(VEHICLE_CLASSES) <= set(VCLASS_SIZES)
    for name, vid in (("passenger", "car"), ("car", "car"), ("delivery", "van"), ("van", "van"),
                      ("truck", "truck"), ("bus", "bus"), ("motorcycle", "motorcycle")):
        assert VCLASS_SIZES[name] == fleet[vid]


@pytest.mark.parametrize("agent,msg", [
    ({"x": 1, "y": 1, "vclass": "lorry"}, r"agents\[0\]: vclass: unknown vehicle class 'lorry' \(expected passenger"),
    ({"x": 1, "y": 1, "vclass": "truck", "length": 9, "width": 2}, r"vclass: conflicts with 'length'"),
    ({"x": 1, "y": 1, "manoeuvre": "u_turn"}, r"manoeuvre: unknown manoeuvre 'u_turn' \(expected stop, turn_left"),
    ({"x": 1, "y": 1, "speed": 5, "final_speed": 2, "manoeuvre": "stop"}, r"manoeuvre: 'stop' conflicts with 'final_speed'"),
    ({"x": 1, "y": 1, "heading_to_final": 0.1, "manoeuvre": "turn_left"}, r"manoeuvre: 'turn_left' conflicts with 'heading_to_final'"),
    ({"ahead": 10, "x": 1, "y": 1}, r"ahead: conflicts with 'x'"),
    ({"edge": "E1", "pos": 3, "ahead": 10}, r"edge: conflicts with 'ahead'"),
    ({"edge": "E1"}, r"pos: missing"),
    ({"lane": 1, "pos": 3}, r"edge: missing"),
    ({"edge": 7, "pos": 3}, r"edge: must be an edge id"),
    ({"edge": "E1", "pos": -3}, r"pos: must be metres >= 0"),
    ({"edge": "E1", "pos": 3, "lane": 0.5}, r"lane: must be a lane index >= 0"),
    ({"ahead": 80}, r"ahead: must be metres in \[-50, 50\]"),
    ({"ahead": 10, "lane_offset": "left"}, r"lane_offset: must be a whole number of lanes"),
    ({"x": 1, "y": 1, "vtype": 3}, r"vtype: must be the id of one of the scenario's vTypes"),
    ({"x": 1, "y": 1, "vtype": " "}, r"vtype: must be the id of one of the scenario's vTypes"),
    ({"x": 1, "y": 1, "vtype": "coach", "vclass": "bus"}, r"vtype: conflicts with 'vclass'"),
])
def test_a_users_terms_errors_name_the_key(agent, msg):
    with pytest.raises(TokenFileError, match=r"^t\.toml: agents\[0\]: " + msg.removeprefix(r"agents\[0\]: ")):
        parse_tokens({"agents": [agent]}, "t.toml")
