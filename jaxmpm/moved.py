"""The module paths of jaxmpm before its modules were grouped into layers (model, numerics, stages,
run, io), importable for one release: `from jaxmpm.state import State` still works, with a
DeprecationWarning that names the new path. Each old path is a module of its own in sys.modules
whose attributes are read from the module at its new path."""

from __future__ import annotations

import importlib
import sys
import types
import warnings

# old module path -> new module path
MOVED = {
    "jaxmpm.geometry": "jaxmpm.model.geometry",
    "jaxmpm.scene": "jaxmpm.model.scene",
    "jaxmpm.params": "jaxmpm.model.params",
    "jaxmpm.state": "jaxmpm.model.state",
    "jaxmpm.compile": "jaxmpm.numerics.compile",
    "jaxmpm.forms": "jaxmpm.numerics.forms",
    "jaxmpm.shapes": "jaxmpm.numerics.shapes",
    "jaxmpm.transfer": "jaxmpm.numerics.transfer",
    "jaxmpm.ddmp": "jaxmpm.numerics.ddmp",
    "jaxmpm.fields": "jaxmpm.stages.fields",
    "jaxmpm.nodal": "jaxmpm.stages.nodal",
    "jaxmpm.multifield": "jaxmpm.stages.multifield",
    "jaxmpm.constitutive": "jaxmpm.stages.constitutive",
    "jaxmpm.planning": "jaxmpm.run.planning",
    "jaxmpm.simulate": "jaxmpm.run.simulate",
    "jaxmpm.restart": "jaxmpm.run.restart",
    "jaxmpm.batch": "jaxmpm.run.batch",
    "jaxmpm.distributed": "jaxmpm.run.distributed",
    "jaxmpm.compile_cache": "jaxmpm.run.compile_cache",
    "jaxmpm.tangents": "jaxmpm.run.tangents",
    "jaxmpm.files": "jaxmpm.io.files",
    "jaxmpm.plot": "jaxmpm.io.plot",
    "jaxmpm.scenefile": "jaxmpm.io.scenefile",
}


class MovedModule(types.ModuleType):
    """An old module path: reading an attribute warns (DeprecationWarning naming the new path) and
    returns the attribute of the module at the new path. Setting or deleting one is refused, with
    the new path: it would change this alias, not the module that uses the name."""

    def __init__(self, old: str, new: str):
        super().__init__(old, f"Moved to {new}: import it from there.")
        self.__dict__["new_path"] = new

    def _target(self) -> types.ModuleType:
        warnings.warn(
            f"{self.__name__} moved to {self.new_path}: import from {self.new_path} "
            f"({self.__name__} is removed in the next release)",
            DeprecationWarning,
            stacklevel=3,
        )
        return importlib.import_module(self.new_path)

    def __getattr__(self, name: str):
        if name.startswith("__") and name.endswith("__"):
            raise AttributeError(name)  # module machinery (__path__, __all__, ...) of the old path
        return getattr(self._target(), name)

    def __setattr__(self, name: str, value) -> None:
        raise AttributeError(f"{self.__name__} moved to {self.new_path}: set {name} on {self.new_path}")

    def __delattr__(self, name: str) -> None:
        raise AttributeError(f"{self.__name__} moved to {self.new_path}: delete {name} on {self.new_path}")


def register() -> None:
    """Put every old path in sys.modules (once), so that `import jaxmpm.state` finds it."""
    for old, new in MOVED.items():
        sys.modules.setdefault(old, MovedModule(old, new))


def old_module(name: str) -> types.ModuleType:
    """The old path `jaxmpm.<name>` as an attribute of the package (`jaxmpm.state.State` after
    `import jaxmpm.state`); AttributeError where no module of that name moved."""
    full = f"jaxmpm.{name}"
    if full not in MOVED:
        raise AttributeError(f"module 'jaxmpm' has no attribute {name!r}")
    register()
    return sys.modules[full]
