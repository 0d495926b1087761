"""The owner's description of their robot: a kitchen scale and a ruler -> a parameters file.

    python -m hostsim describe --out params/my-robot.json              # asks, one entry at a time
    python -m hostsim describe --answers answers.json --out FILE       # the same, from a file

What the owner measures (docs/your-robot.md):

- each link's **mass with what it carries** (g): link 1 with the wheel motors, the brick and the
  battery but without the wheels; link 2 with the joint-2 motor if it turns with link 2, ...;
- each link's **length** (mm, joint to joint; link 3 to its tip) and its **balance point** (mm from
  its lower joint: where it balances on a pencil's edge, with its parts on it), and its **width**
  (mm, across the link in the direction it tilts; optional);
- the **wheel**: diameter and mass (one wheel with its tyre), and the **track** (mm between the
  wheels' middles).

How each parameter follows (each entry's ``source`` says it):

- ``m_i`` the mass, ``l_i`` the balance point (the model's centre-of-mass distance; the model puts
  the next joint at twice it, hostsim.model.equations: a link whose balance point is far from its
  middle is flagged), ``rw_m`` half the diameter, ``mw_kg``, ``track_m`` as measured;
- ``J_i`` (about the centre of mass) **estimated**: a uniform box of the link's length L and width w,
  m (L^2 + w^2) / 12, clipped to what a mass between the link's ends with that balance point can
  have at most, m b (L - b) + m w^2 / 12 (all of it at the two ends; the least is 0, all of it at
  the balance point). The rod is the middle of that range, not its truth (a motor at one end, a
  battery in the middle): a standard deviation of INERTIA_SIGMA (50 %) of the logarithm;
- ``J_w`` a disc's, m_w r^2 / 2 (a tyre's mass at the rim makes it up to twice that: 30 %);
- the motors' fields from ``--base`` (params/robot.json: Table 2, or the file ``identify`` wrote).

The file has the format of params/robot.json plus an ``uncertainty`` block (hostsim.model.spread:
the log-covariance, here diagonal: the masses and lengths MASS_SIGMA and LENGTH_SIGMA, each a
ruler's and a scale's reading of a link whose parts must be apportioned) and the owner's
entries (``description``). ``make gains PARAMS=FILE`` designs for it and says whether to deploy or
to measure first; the fall and swing tests (``python -m hostsim fit-robot``) tighten it.
"""
import argparse
import json
import os
import sys

import hostsim
from hostsim.errors import ParameterError, TipbotError
from hostsim.model.params import DEFAULT_PARAMS_PATH, parse_params
from tipbot_fw import fields

MASS_SIGMA = 0.06
LENGTH_SIGMA = 0.06
INERTIA_SIGMA = 0.5
WHEEL_SIGMA = 0.02
WHEEL_INERTIA_SIGMA = 0.3
# A balance point this far from the link's middle (a fraction of its length) breaks the model's
# rods-stacked-at-twice-the-balance-point more than the fit can absorb: said, not refused.
OFF_MIDDLE = 0.2

# (key, prompt, unit, lower bound, upper bound, the paper robot's value as the example)
LINK_ENTRIES = (("mass_g", "mass with what it carries", "g", 1.0, 5000.0),
                ("length_mm", "length, joint to joint (link 3: to its tip)", "mm", 5.0, 1000.0),
                ("balance_mm", "balance point, from its lower joint", "mm", 1.0, 1000.0),
                ("width_mm", "width in the direction it tilts (0 if thin)", "mm", 0.0, 500.0))
WHEEL_ENTRIES = (("diameter_mm", "wheel diameter", "mm", 10.0, 200.0), ("mass_g", "one wheel's mass", "g", 1.0, 1000.0))
TRACK_ENTRY = ("track_mm", "track, between the wheels' middles", "mm", 20.0, 1000.0)
PAPER_EXAMPLE = {"links": [{"mass_g": 663, "length_mm": 200, "balance_mm": 100, "width_mm": 0},
                           {"mass_g": 290, "length_mm": 150, "balance_mm": 75, "width_mm": 0},
                           {"mass_g": 205, "length_mm": 100, "balance_mm": 50, "width_mm": 0}],
                 "wheel": {"diameter_mm": 68, "mass_g": 53}, "track_mm": 255}


def check_answers(doc, source):
    """The entries, validated (DescriptionError-free: ParameterError naming the file and field)."""
    f = fields.Fields(source, ParameterError)
    f.check("<answers>", doc, fields.obj)
    f.require(doc, ("links", "wheel", "track_mm"))
    links = doc["links"]
    if not isinstance(links, list) or len(links) != 3:
        f.fail("links", "must be a list of the 3 links' entries, got %r" % (links,))
    for i, link in enumerate(links):
        f.check("links[%d]" % i, link, fields.obj)
        f.known(link, [e[0] for e in LINK_ENTRIES], "links[%d]." % i)
        f.require(link, [e[0] for e in LINK_ENTRIES[:3]], "links[%d]." % i)
        for key, _, unit, lo, hi in LINK_ENTRIES:
            if key in link:
                f.number("links[%d].%s" % (i, key), link[key], lo=lo, hi=hi, lo_open=False)
        if link["balance_mm"] > link["length_mm"]:
            f.fail("links[%d].balance_mm" % i, "is %g mm, beyond the link's length %g mm" % (link["balance_mm"],
                                                                                           link["length_mm"]))
    f.check("wheel", doc["wheel"], fields.obj)
    f.require(doc["wheel"], [e[0] for e in WHEEL_ENTRIES], "wheel.")
    for key, _, unit, lo, hi in WHEEL_ENTRIES:
        f.number("wheel." + key, doc["wheel"][key], lo=lo, hi=hi, lo_open=False)
    f.number("track_mm", doc["track_mm"], lo=TRACK_ENTRY[3], hi=TRACK_ENTRY[4], lo_open=False)
    return doc


def link_inertia(m, length, balance, width):
    """(J about the centre of mass, its upper bound) of a link (SI): the box estimate, clipped."""
    box = m * (length ** 2 + width ** 2) / 12.0
    most = m * balance * (length - balance) + m * width ** 2 / 12.0
    return min(box, most), most


def build(answers, base_doc, source="the owner's description"):
    """-> (parameters document, warnings) from checked answers and the base parameters document
    (its motors, g, u_max)."""
    doc = json.loads(json.dumps(base_doc))
    doc.pop("uncertainty", None)
    doc["description"] = ("Described by its owner (python -m hostsim describe): masses and lengths measured, "
                          "inertias estimated; motors from the base parameters file. SI units.")
    par = doc["parameters"]
    warnings = []
    sigma = {}

    def put(name, value, how, rel_sigma):
        par[name] = {"value": float("%.6g" % value), "source": how, "uncertainty": rel_sigma}
        sigma[name] = rel_sigma
    for i, link in enumerate(answers["links"], start=1):
        m = link["mass_g"] / 1e3
        length = link["length_mm"] / 1e3
        b = link["balance_mm"] / 1e3
        w = link.get("width_mm", 0.0) / 1e3
        put("m%d_kg" % i, m, "measured: %s, link %d with what it carries, %g g" % (source, i, link["mass_g"]),
            MASS_SIGMA)
        put("l%d_m" % i, b, "measured: %s, link %d's balance point %g mm from its lower joint" % (
            source, i, link["balance_mm"]), LENGTH_SIGMA)
        j, most = link_inertia(m, length, b, w)
        put("j%d_kg_m2" % i, j, "estimated: a uniform box of %g x %g mm and %g g, m (L^2 + w^2)/12 (at most %.3g, "
            "all at the ends; at least 0)" % (link["length_mm"], link.get("width_mm", 0.0), link["mass_g"], most),
            INERTIA_SIGMA)
        if i < 3 and abs(b / length - 0.5) > OFF_MIDDLE:
            warnings.append("link %d balances at %.0f %% of its length: the model puts joint %d at twice the balance "
                            "point (%g mm, not %g mm); the fall and swing tests fit what the model needs" % (
                                i, 100 * b / length, i + 1, 2 * link["balance_mm"], link["length_mm"]))
    wheel = answers["wheel"]
    rw = wheel["diameter_mm"] / 2e3
    mw = wheel["mass_g"] / 1e3
    put("rw_m", rw, "measured: %s, wheel diameter %g mm" % (source, wheel["diameter_mm"]), WHEEL_SIGMA)
    put("mw_kg", mw, "measured: %s, one wheel %g g" % (source, wheel["mass_g"]), WHEEL_SIGMA)
    put("jw_kg_m2", mw * rw ** 2 / 2, "estimated: a disc of the wheel's mass and radius, m r^2/2", WHEEL_INERTIA_SIGMA)
    put("track_m", answers["track_mm"] / 1e3, "measured: %s, track %g mm" % (source, answers["track_mm"]), WHEEL_SIGMA)
    names = sorted(sigma)
    doc["uncertainty"] = {"parameters": names,
                          "log_covariance": [[sigma[a] ** 2 if a == b else 0.0 for b in names] for a in names],
                          "source": "the owner's description: scale and ruler readings, inertias estimated",
                          "measurements": {"description": {"summary": "masses and lengths +-%.0f %%, inertias +-%.0f %% "
                                                           "(one standard deviation)" % (100 * MASS_SIGMA,
                                                                                       100 * INERTIA_SIGMA)}}}
    doc["owner_entries"] = answers
    parse_params(doc, "<%s>" % source)
    return doc, warnings


def ask(entries_doc=None, read=input, write=print):
    """The entries asked one by one (the paper robot's values as examples). -> answers."""
    write("Describe your robot: a kitchen scale and a ruler (docs/your-robot.md). Enter to take the example.")
    out = {"links": [], "wheel": {}}

    def number(prompt, unit, lo, hi, example):
        while True:
            text = read("  %s [%s, e.g. %g]: " % (prompt, unit, example)).strip()
            if not text:
                return float(example)
            try:
                v = float(text)
            except ValueError:
                v = float("nan")
            if lo <= v <= hi:
                return v
            write("    %r is not a number of %s in [%g, %g]" % (text, unit, lo, hi))
    for i in range(3):
        write("link %d%s:" % (i + 1, " (on the axle: with the brick, battery and wheel motors, without the wheels)"
                               if i == 0 else ""))
        link = {}
        for key, prompt, unit, lo, hi in LINK_ENTRIES:
            link[key] = number(prompt, unit, lo, hi, PAPER_EXAMPLE["links"][i][key])
        out["links"].append(link)
    write("wheels:")
    for key, prompt, unit, lo, hi in WHEEL_ENTRIES:
        out["wheel"][key] = number(prompt, unit, lo, hi, PAPER_EXAMPLE["wheel"][key])
    out["track_mm"] = number(TRACK_ENTRY[1], TRACK_ENTRY[2], TRACK_ENTRY[3], TRACK_ENTRY[4], PAPER_EXAMPLE["track_mm"])
    return out


def write_doc(doc, path):
    tmp = path + ".tmp"
    with open(tmp, "w") as f:
        json.dump(doc, f, indent=2)
        f.write("\n")
    os.replace(tmp, path)


def main(argv=None):
    ap = argparse.ArgumentParser(prog=hostsim.command("describe"), description=__doc__.split("\n\n")[0],
                                 epilog=__doc__.split("\n\n", 1)[1], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, metavar="FILE", help="the parameters file to write")
    ap.add_argument("--answers", metavar="FILE", help="the entries as JSON (no questions; the keys of docs/your-robot.md)")
    ap.add_argument("--base", default=DEFAULT_PARAMS_PATH,
                    help="parameters file for the motors, g and u_max (default params/robot.json)")
    a = ap.parse_args(argv)
    try:
        base = fields.read_object(a.base, ParameterError)
        parse_params(base, a.base)
        if a.answers:
            answers = check_answers(fields.read_object(a.answers, ParameterError), a.answers)
        else:
            answers = check_answers(ask(), "<your answers>")
        doc, warnings = build(answers, base)
        write_doc(doc, a.out)
    except (TipbotError, EOFError) as e:
        print("describe: error: %s" % (e if str(e) else "no more answers"), file=sys.stderr)
        return 2
    for w in warnings:
        print("note: " + w)
    p = doc["parameters"]
    print("wrote %s: m %s kg, l %s m, J %s kg m^2 (estimated, +-%.0f %%)" % (
        a.out, ", ".join("%.3g" % p["m%d_kg" % i]["value"] for i in (1, 2, 3)),
        ", ".join("%.3g" % p["l%d_m" % i]["value"] for i in (1, 2, 3)),
        ", ".join("%.3g" % p["j%d_kg_m2" % i]["value"] for i in (1, 2, 3)), 100 * INERTIA_SIGMA))
    print("next: make gains PARAMS=%s (its verdict), then the fall and swing tests (docs/your-robot.md)" % a.out)
    return 0


