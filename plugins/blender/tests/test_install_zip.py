"""The installable zip, as a level artist would use it: ``build_zip.py`` builds it, Blender's
own "Install from Disk" (``preferences.addon_install``) installs it into a temporary user
scripts folder, and enabling it registers the panel, the operators and the preferences.

Run as its own process (the user folders are chosen before bpy starts):
``VENV/bin/python plugins/blender/tests/test_install_zip.py``.
"""

import os
import subprocess
import sys
import tempfile
import unittest

HERE = os.path.dirname(os.path.abspath(__file__))
WORK = tempfile.mkdtemp(prefix="lf-zip-")
os.environ["BLENDER_USER_SCRIPTS"] = os.path.join(WORK, "scripts")
os.environ["BLENDER_USER_CONFIG"] = os.path.join(WORK, "config")

import bpy  # noqa: E402  (after the environment: it reads the user folders at start)
import addon_utils  # noqa: E402


class InstallZip(unittest.TestCase):
    def test_zip_installs_and_registers(self):
        out = os.path.join(WORK, "lightfarm_blender.zip")
        built = subprocess.run([sys.executable, os.path.join(HERE, "..", "build_zip.py"),
                                "--out", out], check=True, capture_output=True, text=True)
        self.assertEqual(built.stdout.strip(), out)
        again = out + ".again.zip"
        subprocess.run([sys.executable, os.path.join(HERE, "..", "build_zip.py"), "--out",
                        again], check=True, capture_output=True)
        with open(out, "rb") as a, open(again, "rb") as b:
            self.assertEqual(a.read(), b.read(), "the zip is not reproducible")
        self.assertEqual(bpy.ops.preferences.addon_install(filepath=out), {"FINISHED"})
        installed = os.path.join(WORK, "scripts", "addons", "lightfarm_blender", "__init__.py")
        self.assertTrue(os.path.exists(installed))
        module = addon_utils.enable("lightfarm_blender", default_set=True)
        self.assertEqual(os.path.abspath(module.__file__), os.path.abspath(installed))
        prefs = bpy.context.preferences.addons["lightfarm_blender"].preferences
        self.assertEqual(prefs.url, "http://127.0.0.1:8080")
        self.assertTrue(hasattr(bpy.types, "LIGHTFARM_PT_panel"))
        for name in ("bake", "cancel", "apply", "export", "import_scene"):
            self.assertTrue(hasattr(bpy.ops.lightfarm, name), name)
        self.assertEqual(bpy.context.scene.lightfarm.mode, "emission")


if __name__ == "__main__":
    unittest.main(verbosity=2)
