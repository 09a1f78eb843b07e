"""Research tooling, outside the installed package: readers and figures of the committed results
(``docs/results``) and the per-layer views of an EPS round that the notebooks draw."""
