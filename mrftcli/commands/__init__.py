"""One click command per module; :mod:`mrftcli.cli` imports them lazily.

Commands only parse options, call one library function and print; no maths here.
"""
