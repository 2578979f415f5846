"""The intra-operative re-solve loop from Python, on cases/brain-shift.toml.

The model is prepared once; it is solved from the unloaded state, then the measured cortical
displacements grow by 10 % (as a new registration would give them) and it is solved again
from the first equilibrium. Run from the repository root:

    python python/examples/resolve.py [SCENE] [MEASURED-NAME]
"""

import sys
import time

import hytled


def main(scene="cases/brain-shift.toml", measured="exposed"):
    t0 = time.perf_counter()
    model = hytled.Model(scene)
    print(f"prepared {len(model.nodes)} nodes in {time.perf_counter() - t0:.2f} s")

    first = model.solve()
    print(f"first solve (from the unloaded state): {first.steps} steps, "
          f"{first.wall_seconds['solve']:.2f} s")

    u = model.measured_displacements(measured) * 1.1
    model.set_measured(measured, u)
    again = model.solve()
    print(f"re-solve after +10 % (warm: {again.warm}): {again.steps} steps, "
          f"{again.wall_seconds['solve']:.2f} s")
    for name, d in again.probes.items():
        print(f"  probe {name}: {d} m")
    return first, again


if __name__ == "__main__":
    main(*sys.argv[1:])
