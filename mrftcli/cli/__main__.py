"""``python -m mrftcli.cli``: the same as the ``mrft-ident`` command."""

from .main import main

main()
