"""The fuzz benchmark's inputs (benchmarks/fuzz.py runs them): the valid inputs of every kind, and
near-valid ones made from them, seeded.

The valid inputs are the shipped examples (examples/tokens/*, scenarios/*) and small files written for
netgenerate's 3x3 grid (a configuration, a demand, vTypes and a bus stop, an edgeData file SUMO itself
wrote). A case stacks one to three mutations: XML attributes deleted, duplicated, swapped or given a
wrong type, NaN, inf, a huge number or a bad time ("1:2:3:4:5"); elements removed, duplicated, unknown
or nested deep; a wrong root; TOML/JSON values replaced the same way; the text truncated, emptied,
replaced by binary junk or made invalid UTF-8. Nothing here reads a case: what the product makes of
one is fuzz.py's.
"""
from __future__ import annotations

import json
import math
import os
import random
import subprocess
import xml.etree.ElementTree as ET

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), ".."))

KINDS = ("tokens", "spec", "sumocfg", "routes", "additional", "edgedata")
# values a near-valid input gets instead of a right one
BAD_VALUES = ("", "abc", "NaN", "nan", "inf", "-inf", "1e308", "-1", "-1e9", "0", "1:2:3:4:5", "99:99",
              "1e-320", "0x10", "  ", "\u00e9\u00e8", "$(echo hi)", "a;b", "'\"", "true", "None", "[]")
BAD_DATA = (None, "", "abc", float("nan"), float("inf"), -float("inf"), 1e308, -1, 0, 10**30, True, [],
            {}, [1, 2, 3], {"x": 1}, "1:2:3:4:5", [[[[[]]]]], "auto", "model")

ROUTES = ('<routes>\n  <vType id="car" length="4.6" maxSpeed="13.9"/>\n'
          '  <route id="r0" edges="A0B0 B0C0"/>\n'
          '  <vehicle id="v0" type="car" route="r0" depart="0"/>\n'
          '  <vehicle id="v1" depart="5" departLane="best"><route edges="A1B1 B1C1"/></vehicle>\n'
          '  <trip id="t0" depart="10" from="A2B2" to="B2C2"/>\n'
          '  <flow id="f0" type="car" begin="0" end="600" period="20" from="A0A1" to="A1A2"/>\n'
          '</routes>\n')
ADDITIONAL = ('<additional>\n  <vType id="truck" vClass="truck" length="10.5" width="2.5"/>\n'
              '  <busStop id="bs" lane="A0B0_0" startPos="20" endPos="40"/>\n'
              '  <inductionLoop id="d0" lane="B0C0_0" pos="50" period="60" file="det.xml"/>\n'
              '</additional>\n')
EDGE_DATA_REQUEST = '<additional>\n  <edgeData id="ed" period="100" file="{out}"/>\n</additional>\n'
CONFIG = ('<configuration>\n  <input>\n    <net-file value="grid.net.xml"/>\n'
          '    <route-files value="grid.rou.xml"/>\n    <additional-files value="grid.add.xml"/>\n'
          '  </input>\n  <time>\n    <begin value="0"/>\n    <end value="600"/>\n    <step-length value="1"/>\n'
          '  </time>\n  <processing>\n    <time-to-teleport value="300"/>\n  </processing>\n'
          '</configuration>\n')


# ---------------------------------------------------------------- the valid inputs

def _sumo_bin(name: str) -> str:
    import sumo
    return os.path.join(sumo.SUMO_HOME, "bin", name)


def _write(path: str, text: str) -> str:
    with open(path, "w") as f:
        f.write(text)
    return path


def build_corpus(work: str) -> dict:
    """The valid inputs by kind (name -> bytes) and the context the readers need, in ``work``."""
    net = os.path.join(work, "grid.net.xml")
    subprocess.run([_sumo_bin("netgenerate"), "--grid", "--grid.number", "3", "--grid.length", "100",
                    "-o", net], check=True, capture_output=True)
    routes = _write(os.path.join(work, "grid.rou.xml"), ROUTES)
    add = _write(os.path.join(work, "grid.add.xml"), ADDITIONAL)
    config = _write(os.path.join(work, "grid.sumocfg"), CONFIG)
    edge_data = os.path.join(work, "edgedata.xml")
    request = _write(os.path.join(work, "ed.add.xml"), EDGE_DATA_REQUEST.format(out=edge_data))
    subprocess.run([_sumo_bin("sumo"), "-n", net, "-r", routes, "-a", request, "-e", "300",
                    "--no-step-log", "--no-warnings"], check=True, capture_output=True)
    os.symlink(os.path.join(ROOT, "networks"), os.path.join(work, "networks"))
    os.makedirs(os.path.join(work, "cases"))
    os.makedirs(os.path.join(work, "scenarios"))
    seeds = {k: {} for k in KINDS}
    for folder, kind in (("examples/tokens", "tokens"), ("scenarios", "spec")):
        for name in sorted(os.listdir(os.path.join(ROOT, folder))):
            with open(os.path.join(ROOT, folder, name), "rb") as f:
                seeds[kind][name] = f.read()
    for kind, path in (("sumocfg", config), ("routes", routes), ("additional", add), ("edgedata", edge_data)):
        with open(path, "rb") as f:
            seeds[kind][os.path.basename(path)] = f.read()
    return {"work": work, "net": net, "routes": routes, "additional": add, "seeds": seeds}


# ---------------------------------------------------------------- mutations

def _xml_mutation(rng: random.Random, root: ET.Element) -> ET.Element:
    """One structural mutation of the tree ``root``; returns the (possibly new) root."""
    nodes = list(root.iter())
    node = rng.choice(nodes)
    op = rng.choice(("del_attr", "bad_attr", "swap_attr", "new_attr", "del_el", "dup_el", "unknown_el",
                     "wrong_root", "deep", "bad_attr", "bad_attr", "move_el"))
    if op == "del_attr" and node.attrib:
        del node.attrib[rng.choice(sorted(node.attrib))]
    elif op == "bad_attr" and node.attrib:
        node.set(rng.choice(sorted(node.attrib)), rng.choice(BAD_VALUES))
    elif op == "swap_attr" and len(node.attrib) > 1:
        a, b = rng.sample(sorted(node.attrib), 2)
        node.attrib[a], node.attrib[b] = node.attrib[b], node.attrib[a]
    elif op == "new_attr":
        node.set(rng.choice(("depart", "begin", "end", "period", "number", "edges", "route", "type", "from",
                             "to", "value", "id", "lane", "pos", "density", "speed", "bogus")),
                 rng.choice(BAD_VALUES))
    elif op in ("del_el", "dup_el", "move_el") and node is not root:
        parent = next(p for p in nodes if node in list(p))
        if op == "del_el":
            parent.remove(node)
        elif op == "dup_el":
            parent.insert(list(parent).index(node), ET.fromstring(ET.tostring(node)))
        else:
            parent.remove(node)
            rng.choice([n for n in root.iter()]).append(node)
    elif op == "unknown_el":
        node.append(ET.Element(rng.choice(("bogus", "vehicle", "interval", "edge", "flow", "include",
                                           "net-file", "route")),
                               {rng.choice(("id", "href", "value", "begin")): rng.choice(BAD_VALUES)}))
    elif op == "wrong_root":
        new = ET.Element(rng.choice(("net", "routes", "additional", "configuration", "meandata", "html",
                                     "add", "data")), dict(root.attrib))
        new.extend(list(root))
        return new
    elif op == "deep":
        el = node
        for _ in range(rng.choice((50, 500, 5000))):
            el = ET.SubElement(el, "x")
    return root


def _data_mutation(rng: random.Random, data):
    """One mutation of a decoded TOML/JSON document (tables and lists mutated in place)."""
    paths = []

    def walk(v, path):
        paths.append(path)
        if isinstance(v, dict):
            for k, x in v.items():
                walk(x, path + (k,))
        elif isinstance(v, list):
            for i, x in enumerate(v):
                walk(x, path + (i,))
    walk(data, ())
    path = rng.choice(paths)
    if not path:
        return rng.choice(BAD_DATA) if rng.random() < 0.1 else data
    parent = data
    for p in path[:-1]:
        parent = parent[p]
    key, op = path[-1], rng.choice(("bad", "bad", "bad", "delete", "dup", "unknown", "deep", "swap"))
    if op == "bad":
        parent[key] = rng.choice(BAD_DATA)
    elif op == "delete":
        del parent[key]
    elif op == "dup":
        if isinstance(parent, list):
            parent.append(json.loads(json.dumps(parent[key])))
        else:
            parent[f"{key}_2"] = parent[key]
    elif op == "unknown" and isinstance(parent, dict):
        parent[rng.choice(("bogus", "x", "center", "auto", "agents", "p_mask", "density", "net"))] = \
            rng.choice(BAD_DATA)
    elif op == "deep":
        v = parent[key]
        for _ in range(rng.choice((20, 200))):
            v = [v] if rng.random() < 0.5 else {"a": v}
        parent[key] = v
    elif op == "swap" and isinstance(parent, dict) and len(parent) > 1:
        a, b = rng.sample(list(parent), 2)
        parent[a], parent[b] = parent[b], parent[a]
    return data


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, float):
        return "nan" if math.isnan(v) else ("inf" if v > 0 else "-inf") if math.isinf(v) else repr(v)
    if isinstance(v, int):
        return str(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, list):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(str(k))} = {_toml_value(x)}" for k, x in v.items()) + "}"
    return '"null"'                       # TOML has no null: the nearest wrong value


def _dump(data, suffix: str) -> bytes:
    if suffix == ".json":
        return json.dumps(data).encode()
    if not isinstance(data, dict):
        return f"value = {_toml_value(data)}\n".encode()
    return "".join(f"{json.dumps(str(k))} = {_toml_value(v)}\n" for k, v in data.items()).encode()


def _text_mutation(rng: random.Random, raw: bytes) -> bytes:
    op = rng.choice(("truncate", "truncate", "empty", "junk", "latin1", "del_line", "dup_line", "swap_lines",
                     "insert_junk", "nul"))
    lines = raw.split(b"\n")
    if op == "truncate":
        return raw[:rng.randrange(len(raw) + 1)]
    if op == "empty":
        return rng.choice((b"", b"\n", b"   "))
    if op == "junk":
        return bytes(rng.randrange(256) for _ in range(rng.randrange(1, 2000)))
    if op == "latin1":
        return raw.replace(b"e", b"\xe9", rng.randrange(1, 5))
    if op == "nul":
        k = rng.randrange(len(raw) + 1)
        return raw[:k] + b"\x00" + raw[k:]
    if op == "insert_junk":
        k = rng.randrange(len(raw) + 1)
        return raw[:k] + bytes(rng.randrange(256) for _ in range(rng.randrange(1, 30))) + raw[k:]
    k = rng.randrange(len(lines))
    if op == "del_line":
        del lines[k]
    elif op == "dup_line":
        lines.insert(k, lines[k])
    else:
        j = rng.randrange(len(lines))
        lines[k], lines[j] = lines[j], lines[k]
    return b"\n".join(lines)


def mutate(rng: random.Random, name: str, raw: bytes) -> bytes:
    """One to three stacked mutations of the valid input ``raw`` (file ``name``)."""
    suffix = os.path.splitext(name)[1]
    for _ in range(rng.choice((1, 1, 2, 3))):
        if rng.random() < 0.25:
            raw = _text_mutation(rng, raw)
            continue
        try:
            if suffix in (".json", ".toml"):
                import tomllib
                text = raw.decode()
                data = json.loads(text) if suffix == ".json" else tomllib.loads(text)
                raw = _dump(_data_mutation(rng, data), suffix)
            else:
                root = _xml_mutation(rng, ET.fromstring(raw))
                raw = ET.tostring(root, encoding="utf-8", xml_declaration=rng.random() < 0.5)
        except (ValueError, ET.ParseError, UnicodeDecodeError, RecursionError):
            raw = _text_mutation(rng, raw)   # no longer parses: text mutations only
    return raw


def cases(ctx: dict, n: int, seed: int, kinds=KINDS):
    """``n`` mutated inputs, (kind, path), round-robin over the kinds, written under ``ctx``'s work."""
    rng = random.Random(seed)
    for i in range(n):
        kind = kinds[i % len(kinds)]
        name, raw = rng.choice(sorted(ctx["seeds"][kind].items()))
        path = os.path.join(ctx["work"], "cases", f"{i:05d}_{name}")
        if kind in ("spec", "sumocfg"):   # where the files they name are found (relative paths)
            path = os.path.join(ctx["work"], "scenarios" if kind == "spec" else "", f"case_{i:05d}_{name}")
        with open(path, "wb") as f:
            f.write(mutate(rng, name, raw))
        yield kind, path

