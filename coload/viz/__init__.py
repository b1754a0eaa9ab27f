"""Standard viewers: a run as MCAP (:mod:`.mcap_export`) and a live view in Foxglove (:mod:`.live`),
both from the messages of :mod:`.scene`. They need the ``viz`` extra (:mod:`coload.extras`). docs/viewers.md.
"""
