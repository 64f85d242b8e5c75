"""Shipped unit frequency / unit gain manifolds (installed as ``mrftcli._manifolds``).

Built by ``mrft-ident build-ufm``; the file format is documented in ``docs/method.md``.
"""
