"""Runs a cloudcontrol project, opens each epoch's orthophoto and plots the checkpoint
errors (plan vectors over the orthophoto, height errors per epoch).

    python run_and_plot.py PROJECT.toml [OUT.png]

Its dependencies come with the package's `examples` extra (`pip install
"cloudcontrol[examples]"`: matplotlib, and rasterio to read the GeoTIFFs). `cloudcontrol
demo` writes a project to try it on: cloudcontrol_demo/block/project.toml.
"""
import sys
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt
import numpy as np
import rasterio

import cloudcontrol


def main(project: str, out_png: str = "checkpoints.png") -> None:
    # A partial run (an epoch with photos not oriented) still plots what was oriented.
    res = cloudcontrol.run(project, partial_ok=True)
    epochs = res["report"]["epochs"]
    fig, axes = plt.subplots(1, len(epochs) + 1, figsize=(5 * (len(epochs) + 1), 5))
    for ax, e in zip(axes, epochs):
        ortho = Path(res["output"]) / f"outputs-{e['name']}" / "orthophoto.tif"
        if ortho.exists():
            with rasterio.open(ortho) as ds:
                rgb = np.dstack(ds.read((1, 2, 3)))
                b = ds.bounds
            ax.imshow(rgb, extent=[b.left, b.right, b.bottom, b.top])
        cps = e["checkpoints"]
        if cps:
            x = np.array([c["x"] for c in cps])
            y = np.array([c["y"] for c in cps])
            dx = np.array([c["dx"] for c in cps])
            dy = np.array([c["dy"] for c in cps])
            # Plan errors exaggerated 100× so centimetres show on a map of hundreds of metres.
            ax.quiver(x, y, dx, dy, color="red", angles="xy", scale_units="xy", scale=0.01)
        ax.set_title(f"{e['name']}: plan {e['check_rmse_plan_m']:.2f} m, "
                     f"height {e['check_rmse_height_m']:.2f} m")
    ax = axes[-1]
    for e in epochs:
        dz = [c["dz"] for c in e["checkpoints"]]
        if dz:
            ax.hist(dz, bins=10, alpha=0.6, label=f"{e['name']} (GSD {e['gsd_m']:.2f} m)")
    ax.set_xlabel("height error (m)")
    ax.legend()
    fig.tight_layout()
    fig.savefig(out_png, dpi=100)
    print(f"wrote {out_png}")


if __name__ == "__main__":
    main(*sys.argv[1:])
