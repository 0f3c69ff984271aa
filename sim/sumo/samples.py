"""The sample SUMO network of the larger scenario: 3.4 km of three-lane motorway with an on-ramp.

``motorway_ramp_plain`` (pure) gives SUMO's plain node, edge and connection files: ``main_a`` (1.4 km) and
``main_b`` (2 km), three 3.5 m lanes at 25 m/s, meet at the junction ``j``, where the one-lane ``ramp``
(25 m/s, curving in from the south-west) joins lane 0; the ramp has the right of way there (the motorway's
lane 0 gives way to what comes down it). ``write_sample`` builds it
with netconvert and writes the corridor file for it (``sim.sumo.corridor``) with eight RSUs along the
motorway round the junction: what a user does with a network of their own.

    python -m sim.sumo.samples --out deploy/corridors
"""

from __future__ import annotations

import argparse
from pathlib import Path

from sim.sumo.corridor import write_corridor
from sim.sumo.network import build_net

SAMPLE = "motorway_ramp"
MAIN_ROUTE = ("main_a", "main_b")
RAMP_ROUTE = ("ramp", "main_b")
SAMPLE_RSUS = (("rsu1", "main_a", 1250.0), ("rsu2", "main_a", 1350.0), ("rsu3", "main_b", 50.0),
               ("rsu4", "main_b", 150.0), ("rsu5", "main_b", 250.0), ("rsu6", "main_b", 350.0),
               ("rsu7", "main_b", 450.0), ("rsu8", "main_b", 550.0))
"""(id, edge, position along it) of the sample corridor's RSUs: about 100 m apart, from 150 m before the junction."""


def motorway_ramp_plain() -> tuple[str, str, str]:
    """(nodes, edges, connections) plain XML of the sample network."""
    nodes = ('<nodes>\n'
             '  <node id="w" x="0" y="0"/>\n'
             '  <node id="j" x="1400" y="0" type="priority"/>\n'
             '  <node id="e" x="3400" y="0"/>\n'
             '  <node id="r0" x="850" y="-240"/>\n'
             '</nodes>\n')
    edges = ('<edges>\n'
             '  <edge id="main_a" from="w" to="j" numLanes="3" speed="25" width="3.5" priority="3"/>\n'
             '  <edge id="main_b" from="j" to="e" numLanes="3" speed="25" width="3.5" priority="3"/>\n'
             '  <edge id="ramp" from="r0" to="j" numLanes="1" speed="25" width="3.5" priority="4" '
             'shape="850,-240 1000,-150 1150,-75 1280,-28 1400,-12"/>\n'
             '</edges>\n')
    cons = ('<connections>\n'
            + "".join(f'  <connection from="main_a" to="main_b" fromLane="{k}" toLane="{k}"/>\n' for k in range(3))
            + '  <connection from="ramp" to="main_b" fromLane="0" toLane="0"/>\n'
            '</connections>\n')
    return nodes, edges, cons


def write_sample(out_dir: str | Path) -> tuple[Path, Path]:
    """Build the sample network and its corridor file in ``out_dir``; returns (network, corridor file)."""
    out_dir = Path(out_dir)
    nodes, edges, cons = motorway_ramp_plain()
    net = build_net(nodes, edges, out_dir / f"{SAMPLE}.net.xml", cons)
    toml = write_corridor(net, list(MAIN_ROUTE), [(r, e, p, 4.5) for r, e, p in SAMPLE_RSUS],
                          out_dir / f"{SAMPLE}.toml", corridor_id=SAMPLE,
                          name="3.4 km three-lane motorway with an on-ramp (SUMO network)",
                          av_start_s_m=1150.0, av_lane=2, av_speed_mps=18.0)
    return net, toml


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m sim.sumo.samples", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="folder for the network and the corridor file")
    args = ap.parse_args(argv)
    for p in write_sample(args.out):
        print(p)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
