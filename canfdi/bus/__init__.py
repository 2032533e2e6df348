"""The bus layer: DBC codecs, the signal map, E2E profiles, sample clocks and frame blocks."""
