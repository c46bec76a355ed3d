"""The app's own Qt controls, one to a module; the panels are built from them."""
