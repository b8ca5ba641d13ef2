#!/usr/bin/env python3
"""Convert Google DeepMind's rally ball states into ttball's launch-state CSV.

Usage: python3 convert_gdm.py /path/to/gdm_ball_states/rallies.json > gdm_rallies.csv

Source: Google DeepMind, "Competitive Robot Table Tennis: Initial Ball States", released with
D'Ambrosio et al., "Achieving Human Level Competitive Robot Table Tennis", ICRA 2025
(arXiv 2408.03906). Licence: CC-BY 4.0.

GDM frame: origin at the centre of the table surface, x across the width, y along the length,
z up. ttball `table` frame: x along the length toward the opponent, y to the left seen from the
robot, z up; incoming balls move toward -x. Records moving toward -y in the GDM frame are the
opponent's hits toward the robot; the proper rotation about z
    x_ttball = y_gdm,   y_ttball = -x_gdm,   z_ttball = z_gdm
is applied to position, velocity and spin alike (spin is an axial vector, and a proper rotation
transforms it like a polar one). Only records with vel_y < 0 (GDM frame) are kept. Values are
written with 6 significant digits, records in the input's order.
"""

import json
import sys


def fmt(value):
    return "%.6g" % value


def main(argv):
    if len(argv) != 2:
        sys.stderr.write("usage: convert_gdm.py RALLIES_JSON\n")
        return 2
    with open(argv[1], encoding="utf-8") as f:
        records = json.load(f)
    kept = [r for r in records if r["vel_y"] < 0.0]
    out = sys.stdout
    out.write(
        "# Google DeepMind, \"Competitive Robot Table Tennis: Initial Ball States\" "
        "(D'Ambrosio et al., ICRA 2025, arXiv 2408.03906), rallies.json, CC-BY 4.0. "
        "Converted by convert_gdm.py: %d of %d records, those with vel_y < 0 (moving toward "
        "the robot); frame table: x = y_gdm, y = -x_gdm, z = z_gdm for position, velocity "
        "and spin; SI units (m, m/s, rad/s); 6 significant digits.\n" % (len(kept), len(records))
    )
    out.write("id,x,y,z,vx,vy,vz,wx,wy,wz\n")
    for r in kept:
        row = [
            r["pos_y"], -r["pos_x"], r["pos_z"],
            r["vel_y"], -r["vel_x"], r["vel_z"],
            r["w_vel_y"], -r["w_vel_x"], r["w_vel_z"],
        ]
        out.write("%d,%s\n" % (int(r["id"]), ",".join(fmt(v) for v in row)))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
