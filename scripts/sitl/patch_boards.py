"""Switch CAN and littlefs off in ArduPilot's SITL board (their submodules are not needed headless).

usage: python patch_boards.py Tools/ardupilotwaf/boards.py   (idempotent)
"""
import re
import sys

path = sys.argv[1]
text = open(path, encoding="utf-8").read()
start = text.index("class sitl(Board):")
end = text.index("\nclass ", start + 10)
body = text[start:end]
init = re.search(r"def __init__\(self\):\n(\s+)super\(sitl, self\).__init__\(\)\n", body)
if init is None:
    init = re.search(r"def __init__\(self\):\n(\s+)super\(\)\.__init__\(\)\n", body)
if init is None:
    sys.exit("patch_boards: sitl.__init__ not found; set with_can/with_littlefs = False by hand")
if "self.with_can = False" not in body:
    ind = init.group(1)
    new = init.group(0) + f"{ind}self.with_can = False\n{ind}self.with_littlefs = False  # mrft-ident SITL\n"
    body = body.replace(init.group(0), new, 1)
    # later assignments in __init__ must not switch them back on
    body = re.sub(r"\n(\s+)self\.with_can = True", r"\n\1self.with_can = False", body)
    body = re.sub(r"\n(\s+)self\.with_littlefs = True", r"\n\1self.with_littlefs = False", body)
    open(path, "w", encoding="utf-8").write(text[:start] + body + text[end:])
print("patched" if "self.with_can = False" in body else "unchanged", path)
