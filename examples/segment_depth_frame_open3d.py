"""Segment a depth frame and draw the regions with Open3D (a PLY and a PNG when there is no display).

    python examples/segment_depth_frame_open3d.py [--out out/depth_example] [--no-window]

The frame is a simulated 640 x 480 depth camera image in millimetres (a room with two
cylinders and a sphere), read the way a real frame would be: ``OrganizedCloud.from_depth``
with the camera's intrinsics. The ``rgbd_vga`` preset segments it. With a display an
Open3D window shows the points coloured by region; without one (or with ``--no-window``)
the coloured points go to ``regions.ply`` and the range / residual / edges / labels panel to
``panel.png``.
"""

import argparse
import os
from pathlib import Path

import numpy as np

import rangeseg_o3d as rs
from rangeseg_o3d.synthetic.depth_camera import simulate_depth_camera
from rangeseg_o3d.synthetic.suite import rgbd_scenes


def depth_frame_mm(seed: int = 0):
    """A simulated uint16 depth image (mm) and its intrinsics (fx, fy, cx, cy)."""
    name, scene = rgbd_scenes()[1]  # the room with cylinders and a sphere
    cloud = simulate_depth_camera(scene, seed=seed).cloud
    z = np.nan_to_num(cloud.xyz[..., 2], nan=0.0)
    camera = cloud.geometry
    return np.round(z * 1000.0).astype(np.uint16), (camera.fx, camera.fy, camera.cx, camera.cy)


def coloured_points(cloud, result):
    """An Open3D point cloud of the valid pixels, coloured by region (grey outside regions)."""
    import open3d as o3d

    from rangeseg_o3d.viz.colors import region_colors

    valid = cloud.valid
    colours = region_colors(result)[result.labels[valid]] / 255.0
    points = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud.xyz[valid]))
    points.colors = o3d.utility.Vector3dVector(colours)
    return points


def has_display() -> bool:
    return bool(os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY"))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", type=Path, default=Path("out/depth_example"),
                        help="folder for regions.ply and panel.png when no window is shown")
    parser.add_argument("--no-window", action="store_true", help="write files even when a display exists")
    args = parser.parse_args()

    depth, (fx, fy, cx, cy) = depth_frame_mm()
    cloud = rs.OrganizedCloud.from_depth(depth, fx, fy, cx, cy, depth_scale=0.001)
    result = rs.Pipeline("rgbd_vga").run(cloud)
    kinds = [f.kind for f in result.features]
    counts = ", ".join(f"{kind} {kinds.count(kind)}" for kind in ("plane", "cylinder", "sphere"))
    print(f"{depth.shape[1]} x {depth.shape[0]} depth frame: {len(kinds)} features ({counts}) "
          f"in {1000 * result.timings['total']:.1f} ms")

    points = coloured_points(cloud, result)
    if has_display() and not args.no_window:
        import open3d as o3d

        o3d.visualization.draw_geometries([points], window_name="rangeseg_o3d regions")
        return
    import open3d as o3d

    from rangeseg_o3d.viz.panel import write_panel_png

    args.out.mkdir(parents=True, exist_ok=True)
    o3d.io.write_point_cloud(str(args.out / "regions.ply"), points)
    write_panel_png(args.out / "panel.png", cloud, result)
    print(f"no window: wrote {args.out / 'regions.ply'} and {args.out / 'panel.png'}")


if __name__ == "__main__":
    main()
