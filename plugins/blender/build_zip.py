"""Builds the installable add-on zip: ``dist/lightfarm_blender-<version>.zip`` holding the
``lightfarm_blender`` package (Blender: Edit > Preferences > Add-ons > Install from Disk).

Plain Python 3 (no bpy). The zip is reproducible: files sorted, fixed timestamps, so the same
sources give the same bytes.

Usage: ``python3 plugins/blender/build_zip.py [--out PATH]``; prints the path written.
"""

import argparse
import ast
import os
import zipfile

HERE = os.path.dirname(os.path.abspath(__file__))
PACKAGE = "lightfarm_blender"


def version():
    """``bl_info["version"]`` of the package, as ``"0.1.0"``."""
    with open(os.path.join(HERE, PACKAGE, "__init__.py"), encoding="utf-8") as f:
        tree = ast.parse(f.read())
    for node in tree.body:
        if isinstance(node, ast.Assign) and getattr(node.targets[0], "id", "") == "bl_info":
            info = ast.literal_eval(node.value)
            return ".".join(str(v) for v in info["version"])
    raise SystemExit(f"{PACKAGE}/__init__.py has no bl_info")


def build(out):
    os.makedirs(os.path.dirname(out) or ".", exist_ok=True)
    files = sorted(name for name in os.listdir(os.path.join(HERE, PACKAGE))
                   if name.endswith(".py"))
    with zipfile.ZipFile(out, "w", zipfile.ZIP_DEFLATED) as archive:
        for name in files:
            info = zipfile.ZipInfo(f"{PACKAGE}/{name}", date_time=(2026, 1, 1, 0, 0, 0))
            info.compress_type = zipfile.ZIP_DEFLATED
            info.external_attr = 0o644 << 16
            with open(os.path.join(HERE, PACKAGE, name), "rb") as f:
                archive.writestr(info, f.read())
    return out


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default=os.path.join(HERE, "dist",
                                                      f"{PACKAGE}-{version()}.zip"))
    print(build(parser.parse_args().out))
