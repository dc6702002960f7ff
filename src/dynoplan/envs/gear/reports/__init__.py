"""The gear's reports: its results table (:mod:`.results`), the figures of its learned
models (:mod:`.figures`) and one evaluation episode replayed or rendered (:mod:`.episode`)."""
