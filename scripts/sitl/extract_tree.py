"""Write the tree of one commit of a bare git repository into a folder, skipping blobs it lacks.

Snapshots of large public repositories can miss a few large binary files (prebuilt libraries, test
data); ``git archive`` stops at the first one. This writes every file that is there and counts the
rest (after /work/shared/sitl/extract_snapshot.py).

usage: python extract_tree.py GIT_DIR REV DEST
"""

import os
import subprocess
import sys


def extract(git_dir: str, rev: str, dest: str) -> tuple[int, int]:
    """Write REV's files under DEST; (written, missing)."""
    tree = subprocess.run(["git", "--git-dir", git_dir, "ls-tree", "-r", rev], capture_output=True,
                          text=True, check=True).stdout.splitlines()
    cat = subprocess.Popen(["git", "--git-dir", git_dir, "cat-file", "--batch"], stdin=subprocess.PIPE,
                           stdout=subprocess.PIPE)
    assert cat.stdin is not None and cat.stdout is not None
    written = missing = 0
    for line in tree:
        meta, path = line.split("\t", 1)
        mode, typ, sha = meta.split()
        if typ != "blob":
            continue
        cat.stdin.write((sha + "\n").encode())
        cat.stdin.flush()
        header = cat.stdout.readline().decode().split()
        if header[-1] == "missing":
            missing += 1
            continue
        data = cat.stdout.read(int(header[2]))
        cat.stdout.read(1)
        target = os.path.join(dest, path)
        os.makedirs(os.path.dirname(target), exist_ok=True)
        if mode == "120000":
            if not os.path.lexists(target):
                os.symlink(data.decode(), target)
            continue
        with open(target, "wb") as out:
            out.write(data)
        if mode == "100755":
            os.chmod(target, 0o755)
        written += 1
    cat.stdin.close()
    cat.wait()
    return written, missing


if __name__ == "__main__":
    n, miss = extract(*sys.argv[1:4])
    print("files", n, "missing", miss)
