"""The side panels, one to a module, built from sweepedit.app.widgets: the primitives
list, the selected primitive's properties, and fitting.

Panels read the Document and turn widget edits into commands on the CommandStack; they
refresh themselves from the Document's signals (so undo updates them too), blocking
their own widgets' signals while they do so that a refresh never becomes an edit, and
disconnect from the Document when they are destroyed.
"""

from sweepedit.app.panels.fit import FitPanel
from sweepedit.app.panels.primitive_list import PrimitiveListPanel
from sweepedit.app.panels.properties import PropertiesPanel

__all__ = ["FitPanel", "PrimitiveListPanel", "PropertiesPanel"]
