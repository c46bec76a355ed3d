"""Qt + PyVista editor: window, scene, panels, background worker, undo commands."""
