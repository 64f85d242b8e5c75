"""Compare identified loops against a baseline (``mrft-ident compare``)."""
