"""The library behind the verbs: what `canfdi run`, `demo`, `capture`, `replay`, `bench`,
`soak`, `evaluate`, `calibrate`, `identify`, `fleet`, `report` and `export` compute, one module
per verb (a verb's library never imports another's), and what several verbs share: the
monitoring session (session.py), the reports' look (figures.py), the pairing of shipped configs
and scenarios (pairing.py), a log's samples (samples.py). Nothing here parses a command line or
prints; canfdi.cli does."""
