"""``python -m mrftcli``: the same as the ``mrft-ident`` command (the tests call the CLI this way, so they do
not depend on the environment's ``bin`` being on PATH)."""

from .cli.main import main

main()
