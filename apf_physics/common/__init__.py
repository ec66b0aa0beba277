"""Foundations that know nothing of worlds: planar geometry, compiled loops, the signed log, and
reading and writing users' files within limits (``safefile``, ``safeyaml``)."""
