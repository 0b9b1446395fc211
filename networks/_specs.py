"""Builders for the small networks used by networks/build.py.

Each builder is a plain function ``builder(ws)`` taking a build workspace
(see ``Workspace`` in build.py) and calling exactly one of
``ws.netgenerate(*args)`` or ``ws.netconvert(nodes, edges, *args, roundabouts=...)``.
The function name is the network name, its docstring the README description.
Speeds are in m/s: 8.33=30, 11.11=40, 13.89=50, 16.67=60, 22.22=80,
27.78=100, 33.33=120 km/h.
"""
import math

# pedestrian infrastructure: sidewalks on roads up to 60 km/h, guessed crossings
PEDESTRIANS = ("--sidewalks.guess", "--sidewalks.guess.max-speed", 16.7, "--crossings.guess")


# ---------------------------------------------------------------- plain-XML helpers
def node(nid, x, y, jtype=None):
    n = {"id": nid, "x": x, "y": y}
    if jtype:
        n["type"] = jtype
    return n


def road(a, b, lanes=1, speed=13.89, priority=None, shape=None, two_way=True):
    """Edge a->b (and b->a unless one-way); shape includes the end points."""
    def edge(f, t, pts):
        e = {"id": "%s_%s" % (f, t), "from": f, "to": t, "numLanes": lanes, "speed": speed}
        if priority is not None:
            e["priority"] = priority
        if pts:
            e["shape"] = pts
        return e
    out = [edge(a, b, shape)]
    if two_way:
        out.append(edge(b, a, shape[::-1] if shape else None))
    return out


def arc(cx, cy, r, a0, a1, step=15.0):
    """Points on a counter-clockwise circular arc from angle a0 to a1 (degrees)."""
    n = max(2, int(math.ceil((a1 - a0) / step)) + 1)
    return [(cx + r * math.cos(math.radians(a0 + (a1 - a0) * i / (n - 1))),
             cy + r * math.sin(math.radians(a0 + (a1 - a0) * i / (n - 1)))) for i in range(n)]


def roundabout(prefix, cx, cy, r, angles, lanes=1, speed=8.33):
    """Counter-clockwise (right-hand traffic) roundabout with one ring node per arm angle.

    Returns (nodes, edges, roundabout) where roundabout is the explicit
    ``<roundabout>`` element for the edge file."""
    angles = sorted(angles)
    ids = ["%s%d" % (prefix, k) for k in range(len(angles))]
    nodes = [node(i, cx + r * math.cos(math.radians(a)), cy + r * math.sin(math.radians(a)), "priority")
             for i, a in zip(ids, angles)]
    edges = []
    for k, a in enumerate(angles):
        k1 = (k + 1) % len(angles)
        a1 = angles[k1] + (360 if k1 == 0 else 0)
        edges += road(ids[k], ids[k1], lanes, speed, priority=10, shape=arc(cx, cy, r, a, a1), two_way=False)
    return nodes, edges, {"nodes": " ".join(ids), "edges": " ".join(e["id"] for e in edges)}


def polar(r, deg):
    return r * math.cos(math.radians(deg)), r * math.sin(math.radians(deg))


# ---------------------------------------------------------------- netgenerate networks
def grid3x3_1lane(ws):
    """3x3 grid, 100 m blocks, 1 lane, 13.89 m/s, priority junctions, u-turns everywhere."""
    ws.netgenerate("--grid", "--grid.number", 3, "--grid.length", 100,
                   "-L", 1, "-S", 13.89, "-j", "priority")


def grid4x4_2lane_tls(ws):
    """4x4 grid, 150 m blocks, 2 lanes, 13.89 m/s, all traffic lights, sidewalks + crossings."""
    ws.netgenerate("--grid", "--grid.number", 4, "--grid.length", 150,
                   "-L", 2, "-S", 13.89, "-j", "traffic_light", "--no-turnarounds.tls", *PEDESTRIANS)


def grid5x3_3lane(ws):
    """5x3 grid, 200x150 m blocks with 100 m stubs, 3 lanes, 16.67 m/s, guessed traffic lights."""
    ws.netgenerate("--grid", "--grid.x-number", 5, "--grid.y-number", 3,
                   "--grid.x-length", 200, "--grid.y-length", 150, "--grid.attach-length", 100,
                   "-L", 3, "-S", 16.67, "-j", "priority", "--tls.guess", "--no-turnarounds.except-deadend")


def grid6x6_rbl(ws):
    """6x6 residential grid, 80 m blocks, 1 lane, 8.33 m/s, right-before-left, sidewalks + crossings."""
    ws.netgenerate("--grid", "--grid.number", 6, "--grid.length", 80,
                   "-L", 1, "-S", 8.33, "-j", "right_before_left", *PEDESTRIANS)


def grid5x5_jitter(ws):
    """5x5 grid (120 m) with normal(0,12 m) node jitter, 1-2 lanes, 11.11 m/s, guessed traffic lights."""
    ws.netgenerate("--grid", "--grid.number", 5, "--grid.length", 120,
                   "--perturb-x", "norm(0,12)", "--perturb-y", "norm(0,12)",
                   "-L", 2, "--random-lanenumber", "-S", 11.11, "-j", "priority",
                   "--tls.guess", "--tls.guess.threshold", 60)


def spider6x4(ws):
    """Spider net, 6 arms x 4 rings of 80 m, 1 lane, 13.89 m/s, priority junctions, traffic light at the centre."""
    # netgenerate makes the 6-arm centre node (A1) unregulated; signalise it instead
    ws.netgenerate("--spider", "--spider.arm-number", 6, "--spider.circle-number", 4,
                   "--spider.space-radius", 80, "-L", 1, "-S", 13.89, "-j", "priority", "--tls.set", "A1")


def spider8x3_tls(ws):
    """Spider net without centre, 8 arms x 3 rings of 120 m, 2 lanes, 16.67 m/s, guessed traffic lights."""
    ws.netgenerate("--spider", "--spider.arm-number", 8, "--spider.circle-number", 3,
                   "--spider.space-radius", 120, "--spider.omit-center", "--spider.attach-length", 80,
                   "-L", 2, "-S", 16.67, "-j", "priority", "--tls.guess", "--no-turnarounds.tls")


def random_sparse(ws):
    """Random planar net (--rand), 60 iterations, 100-250 m edges, 1 lane, 13.89 m/s, priority."""
    ws.netgenerate("--rand", "--rand.iterations", 60, "--rand.min-distance", 100,
                   "--rand.max-distance", 250, "--rand.min-angle", 35, "--rand.connectivity", 0.9,
                   "-L", 1, "-S", 13.89, "-j", "priority")


def random_grid_tls(ws):
    """Random net on a 120 m lattice (--rand.grid), 1-2 lanes, 16.67 m/s, guessed traffic lights, sidewalks."""
    ws.netgenerate("--rand", "--rand.grid", "--rand.iterations", 45, "--rand.min-distance", 120,
                   "--rand.max-distance", 250, "--rand.connectivity", 0.95,
                   "-L", 2, "--random-lanenumber", "-S", 16.67, "-j", "priority",
                   "--tls.guess", "--tls.guess.threshold", 50, "--no-turnarounds.tls", *PEDESTRIANS)


# ---------------------------------------------------------------- hand-written plain-XML networks
def arterial_tls(ws):
    """1.2 km arterial (3 lanes/dir, 16.67 m/s) with 5 cross streets: traffic lights at 2-lane
    collectors (13.89), priority at 1-lane residential streets (8.33); sidewalks + crossings."""
    nodes = [node("W", 0, 0, "priority"), node("E", 1200, 0, "priority")]
    edges, prev = [], "W"
    for k, x in enumerate(range(200, 1001, 200)):
        collector = k % 2 == 0
        c, s, n = "C%d" % k, "S%d" % k, "N%d" % k
        nodes += [node(c, x, 0, "traffic_light" if collector else "priority"),
                  node(s, x + 10 * (k - 2), -160, "priority"), node(n, x - 10 * (k - 2), 160, "priority")]
        lanes, speed = (2, 13.89) if collector else (1, 8.33)
        edges += road(prev, c, 3, 16.67, priority=3)
        edges += road(s, c, lanes, speed, priority=1) + road(c, n, lanes, speed, priority=1)
        prev = c
    edges += road(prev, "E", 3, 16.67, priority=3)
    ws.netconvert(nodes, edges, "--no-turnarounds.tls", *PEDESTRIANS)


def roundabout_4arm(ws):
    """Single-lane roundabout (r=25 m, 8.33 m/s) with 4 arms of 200 m (13.89 m/s), sidewalks + crossings."""
    rnodes, redges, rb = roundabout("R", 0, 0, 25, [0, 90, 180, 270])
    nodes, edges = list(rnodes), list(redges)
    for k, a in enumerate([0, 90, 180, 270]):
        nodes.append(node("A%d" % k, *polar(225, a), "priority"))
        edges += road("A%d" % k, "R%d" % k, 1, 13.89, priority=1)
    ws.netconvert(nodes, edges, "--roundabouts.guess", *PEDESTRIANS, roundabouts=[rb])


def roundabout_5arm_2lane(ws):
    """Two-lane roundabout (r=40 m, 11.11 m/s) with 5 irregular arms (2 lanes, 16.67 m/s),
    one arm leading to a downstream traffic-light junction."""
    angles = [10, 80, 150, 215, 290]
    rnodes, redges, rb = roundabout("R", 0, 0, 40, angles, lanes=2, speed=11.11)
    nodes, edges = list(rnodes), list(redges)
    for k, a in enumerate(angles):
        nodes.append(node("A%d" % k, *polar(260, a), "traffic_light" if k == 0 else "priority"))
        edges += road("A%d" % k, "R%d" % k, 2, 16.67, priority=2)
    ax, ay = polar(260, angles[0])
    nodes += [node("B0", ax + 30, ay + 180, "priority"), node("B1", ax + 20, ay - 180, "priority")]
    edges += road("B0", "A0", 1, 13.89, priority=1) + road("A0", "B1", 1, 13.89, priority=1)
    ws.netconvert(nodes, edges, "--roundabouts.guess", "--no-turnarounds.except-deadend", roundabouts=[rb])


def highway_ramps(ws):
    """3 km dual-carriageway highway (3 lanes, 33.33/27.78 m/s) with two off- and two on-ramps
    (1 lane, 22.22 m/s) to parallel local roads (2 lanes, 13.89 m/s) with traffic lights; u-turns only at dead ends."""
    nodes = [node(n, x, y, "priority") for n, x, y in [
        ("EB0", 0, -8), ("EB1", 900, -8), ("EB2", 1500, -8), ("EB3", 1900, -8), ("EB4", 3000, -8),
        ("WB0", 3000, 8), ("WB1", 2100, 8), ("WB2", 1500, 8), ("WB3", 1100, 8), ("WB4", 0, 8),
        ("S0", 300, -260), ("S3", 2600, -260), ("N0", 2700, 260), ("N3", 400, 260)]]
    nodes += [node(n, x, y, "traffic_light") for n, x, y in [
        ("S1", 1150, -230), ("S2", 1650, -230), ("N1", 1850, 230), ("N2", 1350, 230)]]
    hw = dict(two_way=False, priority=5)
    edges = (road("EB0", "EB1", 3, 33.33, **hw) + road("EB1", "EB2", 3, 27.78, **hw)
             + road("EB2", "EB3", 3, 27.78, **hw) + road("EB3", "EB4", 3, 33.33, **hw)
             + road("WB0", "WB1", 3, 33.33, **hw) + road("WB1", "WB2", 3, 27.78, **hw)
             + road("WB2", "WB3", 3, 27.78, **hw) + road("WB3", "WB4", 3, 33.33, **hw))
    ramp = dict(two_way=False, priority=2)
    edges += (road("EB1", "S1", 1, 22.22, shape=[(900, -8), (1050, -60), (1150, -230)], **ramp)
              + road("S2", "EB3", 1, 22.22, shape=[(1650, -230), (1750, -60), (1900, -8)], **ramp)
              + road("WB1", "N1", 1, 22.22, shape=[(2100, 8), (1950, 60), (1850, 230)], **ramp)
              + road("N2", "WB3", 1, 22.22, shape=[(1350, 230), (1250, 60), (1100, 8)], **ramp))
    for side in "SN":
        for a, b in zip("0123", "123"):
            edges += road(side + a, side + b, 2, 13.89, priority=3)
    ws.netconvert(nodes, edges, "--ramps.guess", "--no-turnarounds.except-deadend")


def t_junctions(ws):
    """800 m main road (2 lanes, 13.89 m/s) with six T-junctions of mixed control: priority,
    priority_stop, traffic_light, right_before_left; side streets 1 lane 8.33-11.11 m/s, sidewalks."""
    types = ["priority", "priority_stop", "traffic_light", "priority", "right_before_left", "traffic_light"]
    nodes = [node("W", 0, 0, "priority"), node("E", 800, 0, "priority")]
    edges, prev = [], "W"
    for k, jt in enumerate(types):
        x, side = 110 * (k + 1), (1 if k % 2 else -1)
        j, s = "J%d" % k, "T%d" % k
        nodes += [node(j, x, 0, jt), node(s, x + 15 * side, side * (140 + 20 * (k % 3)), "priority")]
        main_lanes = 1 if jt == "right_before_left" else 2
        edges += road(prev, j, main_lanes, 13.89, priority=2)
        edges += road(s, j, 1, 8.33 if k % 2 else 11.11, priority=1)
        prev = j
    edges += road(prev, "E", 2, 13.89, priority=2)
    ws.netconvert(nodes, edges, "--no-turnarounds.tls", *PEDESTRIANS)


def y_junctions(ws):
    """Forking road tree with Y-junctions (2-lane 13.89 m/s trunk, 1-lane 11.11 m/s branches)
    whose leaves are joined by an 8.33 m/s street; priority and allway_stop junctions."""
    pts = {"R": (0, 0), "Y0": (0, 200), "Y1": (-160, 380), "Y2": (160, 380),
           "L0": (-280, 560), "L1": (-90, 580), "L2": (90, 580), "L3": (280, 560)}
    types = {"Y1": "allway_stop", "L1": "allway_stop"}
    nodes = [node(n, x, y, types.get(n, "priority")) for n, (x, y) in pts.items()]
    edges = road("R", "Y0", 2, 13.89, priority=3)
    for a, b in [("Y0", "Y1"), ("Y0", "Y2"), ("Y1", "L0"), ("Y1", "L1"), ("Y2", "L2"), ("Y2", "L3")]:
        edges += road(a, b, 1, 11.11, priority=2)
    for a, b in [("L0", "L1"), ("L1", "L2"), ("L2", "L3")]:
        edges += road(a, b, 1, 8.33, priority=1)
    ws.netconvert(nodes, edges, "--no-turnarounds.except-deadend")
