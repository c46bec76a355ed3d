"""sweepedit for Blender: sweep primitives as native curve objects (see scene.py), the
import / export / abstract-selected-mesh operators (ui.py) and a headless command line
(cli.py). Runs in Blender's own Python; imports nothing of sweepedit."""

bl_info = {
    "name": "sweepedit",
    "author": "sweepedit developers",
    "version": (0, 1, 0),
    "blender": (4, 2, 0),
    "location": "File > Import/Export > sweepedit parameters; Object > Abstract selected mesh",
    "description": "Sweep-surface primitives of sweepedit as editable curve objects",
    "category": "Import-Export",
}


def register() -> None:
    from . import ui
    ui.register()


def unregister() -> None:
    from . import ui
    ui.unregister()
