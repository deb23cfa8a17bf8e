"""Add your own segmenter to the registry and run the whole pipeline with it.

    python examples/custom_segmenter_plugin.py

A segmenter is a function ``run(cloud, **params) -> Segmentation`` with a pydantic model
of its parameters (read off the function's signature by ``registry.params_model``, so
each default is written once), wrapped in a :class:`rangeseg_o3d.Plugin`. Registered in code (as
here) or advertised by an installed package through the entry-point group
``rangeseg_o3d.segmenters``, it is chosen by name in a configuration, validated like the
built-ins, and its regions are fitted and refined by the same pipeline.

This one cuts the scan into bands of equal range: crude, but it shows every part.
"""

import numpy as np

import rangeseg_o3d as rs
from rangeseg_o3d import registry
from rangeseg_o3d.segmentation.regions import label_regions
from rangeseg_o3d.synthetic.lms200 import simulate_lms200
from rangeseg_o3d.synthetic.suite import default_scene


def segment_range_bands(cloud, *, band: float = 0.5, min_region_size: int = 30) -> rs.Segmentation:
    """Regions = connected pixels whose range falls in the same band of width ``band``."""
    ranges = np.linalg.norm(cloud.xyz, axis=2)
    bands = np.floor(np.nan_to_num(ranges, nan=-1.0) / band)
    # a pixel is an edge where its band differs from the next one down or right
    edges = ~cloud.valid
    edges[:-1] |= bands[:-1] != bands[1:]
    edges[:, :-1] |= bands[:, :-1] != bands[:, 1:]
    labels = label_regions(edges, min_size=min_region_size)
    return rs.Segmentation(labels=labels, stages={"bands": bands})


# Validated when a configuration is loaded: types and defaults from the signature, bounds here.
RangeBandsConfig = registry.params_model(segment_range_bands, dict(
    band=dict(gt=0, description="width of one range band, m"),
    min_region_size=dict(ge=1, description="smaller regions are dropped"),
), name="RangeBandsConfig")

PLUGIN = rs.Plugin(name="range_bands", config=RangeBandsConfig, run=segment_range_bands,
                   description="connected pixels of equal range band (an example)")


def main() -> None:
    registry.register("segmenter", PLUGIN, overwrite=True)
    print("segmenters:", ", ".join(registry.available("segmenter")))
    config = rs.load_config({"segmenter": {"name": "range_bands", "params": {"band": 0.75}},
                             "refine": {"enabled": False}})
    scan = simulate_lms200(default_scene(), seed=0)
    result = rs.Pipeline(config).run(scan.cloud)
    print(f"range_bands (band 0.75 m): {int(result.labels.max())} regions, {len(result.features)} fitted")
    for feature in result.features[:5]:
        print(f"  {feature.label:3d} {feature.kind:8s} {feature.n_pixels:5d} px  rms {1000 * feature.rms:.1f} mm")
    try:
        rs.load_config({"segmenter": {"name": "range_bands", "params": {"band": -1}}})
    except ValueError as err:
        print("a bad parameter is refused:", " ".join(line.strip() for line in str(err).splitlines()[:2]))


if __name__ == "__main__":
    main()
