#!/usr/bin/env python3
"""Build the SUMO road networks used by sumo-scendiff.

Usage:
    python networks/build.py                 # build all nets into networks/
    python networks/build.py -o /tmp/nets -s 42 -v
    python networks/build.py --describe      # only re-write README.md / splits.json

Builds a family of small, diverse networks (grids, spider, random, arterial,
roundabouts, highway with ramps, T/Y junctions) plus the ~2x2 km demo network
city.net.xml with netgenerate / netconvert (from the eclipse-sumo pip
package, or $SUMO_HOME/bin, or PATH).  Hand-written nets are emitted as
plain XML (.nod.xml/.edg.xml) into a temporary directory and converted there.
All nets use right-hand traffic and 3.2 m lanes.  The output is deterministic
for a given seed and SUMO version: the timestamp in the netconvert/netgenerate
header comment is removed and tools run on relative paths inside the temp dir.

Afterwards every net is loaded with sumolib (withInternal=True) and checked
(passenger lanes present, expected roundabouts present, size limit), and
networks/README.md (stats table) and networks/splits.json are written.
"""
import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
import zlib

import numpy as np

sys.dont_write_bytecode = True   # keep networks/ free of __pycache__
sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
import _organic  # noqa: E402
import _specs  # noqa: E402
import _wide  # noqa: E402
from _city import city  # noqa: E402

try:
    from tqdm import tqdm
except ImportError:  # progress bar is optional
    tqdm = None

NETWORKS_DIR = os.path.dirname(os.path.abspath(__file__))
LANE_WIDTH = 3.2
SMALL_LIMIT_MB, CITY_LIMIT_MB = 2.0, 10.0

# the registry: every builder is a function ``builder(ws)``; its name is the net name
BUILDERS = [
    _specs.grid3x3_1lane,
    _specs.grid4x4_2lane_tls,
    _specs.grid5x3_3lane,
    _specs.grid6x6_rbl,
    _specs.grid5x5_jitter,
    _specs.spider6x4,
    _specs.spider8x3_tls,
    _specs.random_sparse,
    _specs.random_grid_tls,
    _specs.arterial_tls,
    _specs.roundabout_4arm,
    _specs.roundabout_5arm_2lane,
    _specs.highway_ramps,
    _specs.t_junctions,
    _specs.y_junctions,
    _organic.curvy_town,
    _organic.organic_turnlanes,
    _organic.grid_turnlanes_tls,
    city,
    _wide.osm_irregular,
    _wide.osm_suburb,
    _wide.arterial_lights,
    _wide.dense_urban_grid,
]
# held-out evaluation nets: one grid variant, one tls arterial, one random net, and the city demo
HELDOUT = [_specs.grid5x5_jitter, _specs.arterial_tls, _specs.random_sparse, city]
# shaped like the real cities evaluation runs on: only in the "train_wide" split (the training
# networks and these), so that "train" and what recipes record from it stay as they were
WIDE = [_wide.osm_irregular, _wide.osm_suburb, _wide.arterial_lights, _wide.dense_urban_grid]


def sumo_binary(name):
    """Locate a SUMO binary: eclipse-sumo pip package, then $SUMO_HOME/bin, then PATH."""
    homes = []
    try:
        import sumo
        homes.append(sumo.SUMO_HOME)
    except ImportError:
        pass
    if os.environ.get("SUMO_HOME"):
        homes.append(os.environ["SUMO_HOME"])
    for home in homes:
        path = os.path.join(home, "bin", name)
        if os.path.isfile(path):
            return path, home
    path = shutil.which(name)
    if path is None:
        sys.exit("cannot find SUMO binary '%s'; pip install eclipse-sumo sumolib" % name)
    return path, os.environ.get("SUMO_HOME", os.path.dirname(os.path.dirname(path)))


def fmt(value):
    if isinstance(value, float):
        return "%.2f" % value
    if isinstance(value, (list, tuple)):
        return " ".join("%.2f,%.2f" % (float(x), float(y)) for x, y in value)
    return str(value)


def write_plain(path, root, elements):
    """Write a plain-XML file; elements is a list of (tag, attribute dict) or (tag, attribute dict,
    children: a list of (tag, attribute dict), e.g. an edge's ``split`` elements)."""
    def attributes(attrs):
        return " ".join('%s="%s"' % (k, fmt(v)) for k, v in attrs.items())
    with open(path, "w", encoding="utf-8") as f:
        f.write('<?xml version="1.0" encoding="UTF-8"?>\n<%s>\n' % root)
        for tag, attrs, *children in elements:
            if not children or not children[0]:
                f.write("    <%s %s/>\n" % (tag, attributes(attrs)))
                continue
            f.write("    <%s %s>\n" % (tag, attributes(attrs)))
            for ctag, cattrs in children[0]:
                f.write("        <%s %s/>\n" % (ctag, attributes(cattrs)))
            f.write("    </%s>\n" % tag)
        f.write("</%s>\n" % root)


class Workspace:
    """Temporary build directory for one network; builders call netgenerate or netconvert."""

    def __init__(self, tmpdir, name, seed, verbose=False):
        self.tmpdir, self.name, self.seed, self.verbose = tmpdir, name, seed, verbose
        self.output = name + ".net.xml"
        self.expect_roundabouts = 0

    def rng(self):
        return np.random.default_rng([self.seed, zlib.crc32(self.name.encode())])

    def tool_seed(self):
        return (self.seed * 1000003 + zlib.crc32(self.name.encode())) % (2 ** 31)

    def _run(self, tool, args):
        binary, home = sumo_binary(tool)
        cmd = [binary] + [str(a) for a in args] + [
            "--default.lanewidth", LANE_WIDTH, "--junctions.corner-detail", 5,
            "--seed", self.tool_seed(), "-o", self.output]
        cmd = [str(c) for c in cmd]
        env = dict(os.environ, SUMO_HOME=home)
        res = subprocess.run(cmd, cwd=self.tmpdir, env=env, capture_output=True, text=True)
        if self.verbose or res.returncode:
            print("$ %s %s\n%s%s" % (tool, " ".join(cmd[1:]), res.stdout, res.stderr), file=sys.stderr)
        if res.returncode:
            raise RuntimeError("%s failed for %s" % (tool, self.name))

    def netgenerate(self, *args):
        self._run("netgenerate", args)

    def netconvert(self, nodes, edges, *args, roundabouts=()):
        write_plain(os.path.join(self.tmpdir, self.name + ".nod.xml"), "nodes", [("node", n) for n in nodes])
        # an edge's "splits" (lane changes along it, e.g. a turn pocket) are child elements
        write_plain(os.path.join(self.tmpdir, self.name + ".edg.xml"), "edges",
                    [("edge", {k: v for k, v in e.items() if k != "splits"},
                      [("split", sp) for sp in e.get("splits", ())]) for e in edges]
                    + [("roundabout", r) for r in roundabouts])
        self.expect_roundabouts = len(roundabouts)
        self._run("netconvert", ["-n", self.name + ".nod.xml", "-e", self.name + ".edg.xml"] + list(args))


def build(builder, out_dir, seed, verbose):
    """Run one builder in a fresh temp dir and copy the normalised net to out_dir."""
    name = builder.__name__
    with tempfile.TemporaryDirectory(prefix="scendiff_net_") as tmp:
        ws = Workspace(tmp, name, seed, verbose)
        builder(ws)
        with open(os.path.join(tmp, ws.output), encoding="utf-8") as f:
            text = f.read()
    # drop the generation timestamp from the header comment -> byte-identical rebuilds
    text = re.sub(r"<!-- generated on \S+ by ", "<!-- generated by networks/build.py with ", text, count=1)
    path = os.path.join(out_dir, ws.output)
    with open(path, "w", encoding="utf-8", newline="\n") as f:
        f.write(text)
    return path, ws.expect_roundabouts


def describe(path):
    """Load a net with sumolib and collect statistics."""
    import sumolib
    net = sumolib.net.readNet(path, withInternal=True)
    normal = [e for e in net.getEdges() if e.getFunction() == ""]
    drive = [lane for e in normal for lane in e.getLanes() if lane.allows("passenger")]
    walk = [lane for e in normal for lane in e.getLanes() if lane.getPermissions() == {"pedestrian"}]
    jtypes = {}
    for n in net.getNodes():
        if n.getType() != "internal":
            jtypes[n.getType()] = jtypes.get(n.getType(), 0) + 1
    (xmin, ymin), (xmax, ymax) = net.getBBoxXY()
    return {
        "extent": (xmax - xmin, ymax - ymin),
        "edges": len(normal),
        "lanes": sum(e.getLaneNumber() for e in normal),
        "drivable_lanes": len(drive),
        "sidewalks": len(walk),
        "crossings": sum(1 for e in net.getEdges() if e.getFunction() == "crossing"),
        "junctions": dict(sorted(jtypes.items())),
        "tls": len(net.getTrafficLights()),
        "roundabouts": len(net.getRoundabouts()),
        "speeds": sorted({round(lane.getSpeed(), 2) for lane in drive}),
        "scc": drivable_scc_share(net),
        "size_kb": os.path.getsize(path) / 1024.0,
    }


def drivable_scc_share(net):
    """Share of passenger edges in the largest strongly connected component (iterative Tarjan)."""
    edges = [e for e in net.getEdges() if e.getFunction() == "" and e.allows("passenger")]
    succ = {e: [o for o in e.getOutgoing() if o.getFunction() == "" and o.allows("passenger")] for e in edges}
    index, low, on_stack, stack, best, counter = {}, {}, set(), [], 0, 0
    for root in edges:
        if root in index:
            continue
        work = [(root, 0)]
        while work:
            v, i = work.pop()
            if i == 0:
                index[v] = low[v] = counter
                counter += 1
                stack.append(v)
                on_stack.add(v)
            if i < len(succ[v]):
                work.append((v, i + 1))
                w = succ[v][i]
                if w not in index:
                    work.append((w, 0))
                elif w in on_stack:
                    low[v] = min(low[v], index[w])
                continue
            if low[v] == index[v]:
                size = 0
                while True:
                    w = stack.pop()
                    on_stack.discard(w)
                    size += 1
                    if w is v:
                        break
                best = max(best, size)
            if work:
                parent = work[-1][0]
                low[parent] = min(low[parent], low[v])
    return best / max(1, len(edges))


def validate(name, stats, expect_roundabouts):
    problems = []
    if stats["drivable_lanes"] == 0:
        problems.append("no lanes allowing passenger cars")
    if stats["roundabouts"] < expect_roundabouts:
        problems.append("expected %d roundabouts, found %d" % (expect_roundabouts, stats["roundabouts"]))
    limit = CITY_LIMIT_MB if name == city.__name__ else SMALL_LIMIT_MB
    if stats["size_kb"] > limit * 1024:
        problems.append("file too large: %.0f KB" % stats["size_kb"])
    if problems:
        raise RuntimeError("%s: %s" % (name, "; ".join(problems)))


def doc(builder):
    return " ".join(builder.__doc__.split())


def split_of(builder):
    return "heldout" if builder in HELDOUT else "train_wide" if builder in WIDE else "train"


def write_readme(out_dir, rows, seed):
    lines = [
        "# Road networks",
        "",
        "Generated by `networks/build.py` (netgenerate/netconvert from eclipse-sumo, seed %d). "
        "Do not edit the `.net.xml` files by hand; rebuild with:" % seed,
        "",
        "```bash",
        "pip install eclipse-sumo sumolib numpy   # eclipse-sumo/sumolib 1.28.0 used here",
        "python networks/build.py                # options: -o DIR, -s SEED, -v, --describe",
        "```",
        "",
        "All nets: right-hand traffic, 3.2 m lanes, internal links, deterministic output "
        "(rebuilding with the same seed and SUMO version gives byte-identical files). "
        "`splits.json` lists train / train_wide / held-out nets; `city.net.xml` (~2x2 km) is the demo and a "
        "held-out net.",
        "",
        "| network | split | description | extent (m) | edges | lanes (drivable / sidewalk) | "
        "crossings | junction types | TLS | roundabouts | speeds (m/s) | SCC | size (KB) |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for builder, st in rows:
        name = builder.__name__
        jt = ", ".join("%s %d" % kv for kv in st["junctions"].items())
        lines.append("| `%s.net.xml` | %s | %s | %.0f x %.0f | %d | %d (%d / %d) | %d | %s | %d | %d | %s | %.0f%% | %.0f |" % (
            name, split_of(builder), doc(builder), st["extent"][0], st["extent"][1],
            st["edges"], st["lanes"], st["drivable_lanes"], st["sidewalks"], st["crossings"], jt, st["tls"],
            st["roundabouts"], " ".join("%g" % s for s in st["speeds"]), 100 * st["scc"], st["size_kb"]))
    lines += [
        "",
        "Columns: *edges*/*lanes* count normal (non-internal) edges; *SCC* is the share of "
        "passenger edges in the largest strongly connected component (nets without u-turns "
        "or with one-way entries are not fully strongly connected by design).",
        "",
        "The `train_wide` split is `train` plus four networks (`_wide.py`) shaped like the real cities "
        "evaluation runs on (`../shared/nets`, read with sumolib, not copied). Those differ from `train` "
        "in their streets: car edges of median length 30-110 m (`train`: mostly 65-200 m), 30 km/h for "
        "14-52 % of the lane length in 7 of the 9 and 50 km/h for most of the rest (`train`: mostly 50-60 "
        "km/h, up to 120 km/h; no 30 km/h in 11 of the 15), right-before-left junctions in 7 of the 9, "
        "4-23 % one-way streets in the five larger ones, mostly 1-lane streets beside 2-4 lane arterials, "
        "and actuated lights "
        "beside fixed-time ones (Berlin, Wildau; `train` has only fixed-time lights). The four "
        "networks add those: irregular street graphs from `netgenerate --rand` with dead ends and bent "
        "edges (`osm_irregular`, `osm_suburb`), street classes (arterial, collector, residential) with "
        "their speeds, lanes and priorities, 30 km/h right-before-left zones with some 20 km/h streets, "
        "one-way residential streets (kept while every junction reaches every other), left-turn "
        "pockets before the lights of multi-lane arterials (`arterial_lights`), both light types, and "
        "short inner-city blocks (`dense_urban_grid`).",
        "",
    ]
    with open(os.path.join(out_dir, "README.md"), "w", encoding="utf-8", newline="\n") as f:
        f.write("\n".join(lines))


def write_splits(out_dir):
    heldout = [b.__name__ + ".net.xml" for b in BUILDERS if b in HELDOUT]
    train = [b.__name__ + ".net.xml" for b in BUILDERS if b not in HELDOUT and b not in WIDE]
    wide = train + [b.__name__ + ".net.xml" for b in WIDE]
    with open(os.path.join(out_dir, "splits.json"), "w", encoding="utf-8", newline="\n") as f:
        json.dump({"train": train, "train_wide": wide, "heldout": heldout}, f, indent=2)
        f.write("\n")


def get_options(args=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                     formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-o", "--output-dir", default=NETWORKS_DIR,
                        help="directory for the .net.xml files, README.md and splits.json")
    parser.add_argument("-s", "--seed", type=int, default=42, help="random seed for all generators")
    parser.add_argument("-v", "--verbose", action="store_true", help="print tool commands and output")
    parser.add_argument("--describe", action="store_true",
                        help="do not build; only describe/validate existing nets and write README.md/splits.json")
    parser.add_argument("--only", nargs="+", metavar="NAME", choices=[b.__name__ for b in BUILDERS],
                        help="build only these nets; describe the others as they are in the output directory")
    return parser.parse_args(args)


def main(options):
    os.makedirs(options.output_dir, exist_ok=True)
    items = BUILDERS if tqdm is None else tqdm(BUILDERS, desc="networks", unit="net")
    rows = []
    for builder in items:
        start = time.time()
        if options.describe or (options.only and builder.__name__ not in options.only):
            path, expect = os.path.join(options.output_dir, builder.__name__ + ".net.xml"), 0
        else:
            path, expect = build(builder, options.output_dir, options.seed, options.verbose)
        stats = describe(path)
        validate(builder.__name__, stats, expect)
        rows.append((builder, stats))
        if tqdm is None or options.verbose:
            print("%-22s %6.0f x %-6.0f m  edges %4d  lanes %4d  tls %3d  rb %d  scc %3.0f%%  %6.0f KB  %.1fs" % (
                builder.__name__, stats["extent"][0], stats["extent"][1], stats["edges"], stats["lanes"],
                stats["tls"], stats["roundabouts"], 100 * stats["scc"], stats["size_kb"], time.time() - start))
    write_readme(options.output_dir, rows, options.seed)
    write_splits(options.output_dir)


if __name__ == "__main__":
    main(get_options())
