"""Converters of real radar recordings into the sequence format (docs/realdata.md).

The package, file by file:
    radarscenes.py  RadarScenes (2D + Doppler, 4 radars, odometry): `radarscenes.convert(source, radars, t_max)`.
    ti_mmwave.py    TI mmWave RIO demo CSV export (4D, no ground truth): `ti_mmwave.convert(source)`.
    vod.py          View-of-Delft style per-scan point files: `vod.convert(...)`.
    raflow.py       RaFlow demo data (Hasco LRR30-F 4D radar, GNSS/INS poses): `raflow.convert(source)`, one
                    sequence per chain of consecutive frames.
    rosbag.py       ROS 1 / ROS 2 / mcap bags, one PointCloud2 topic: `rosbag.convert(bag, topic, ...)` (needs
                    the rosbags package, imported only when a bag is read).
    _common.py      what they share; its public part is re-exported here: `Conversion`, `ConversionReport`,
                    `CONVERSION_JSON`, `read_csv`, `write_conversion`.
"""

from . import radarscenes, raflow, rosbag, ti_mmwave, vod
from ._common import CONVERSION_JSON, Conversion, ConversionReport, read_csv, write_conversion

__all__ = ["CONVERSION_JSON", "Conversion", "ConversionReport", "radarscenes", "raflow", "read_csv", "rosbag",
           "ti_mmwave", "vod", "write_conversion"]
