"""Converters of real radar recordings into the sequence format (docs/realdata.md).

One module per source format: `radarscenes`, `ti_mmwave`, `vod`; shared helpers in `_common`.
"""
