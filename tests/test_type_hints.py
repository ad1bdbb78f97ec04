"""Every public function of jaxmpm and calibration carries type hints: each parameter (but self and
cls) and the return. Public: a name without a leading underscore, defined in the module that holds
it (not imported there), in a module other than a package's __main__; the public methods (and
property getters) of the public classes defined there count as well."""

import importlib
import inspect
import pkgutil
from collections.abc import Callable, Iterator
from types import ModuleType


import calibration
import jaxmpm

PACKAGES = (jaxmpm, calibration)


def public_modules() -> Iterator[ModuleType]:
    """The packages and every module below them, but the __main__ modules."""
    for package in PACKAGES:
        yield package
        for info in pkgutil.walk_packages(package.__path__, package.__name__ + "."):
            if info.name.rsplit(".", 1)[-1] != "__main__":
                yield importlib.import_module(info.name)


def class_functions(cls: type) -> Iterator[tuple[str, Callable]]:
    """The public methods of a class (static, class and property getters included; not a
    dataclass field's default value, such as a function held by a field)."""
    fields = getattr(cls, "__dataclass_fields__", {})
    for name, member in vars(cls).items():
        if name.startswith("_") or name in fields:
            continue
        if isinstance(member, (staticmethod, classmethod)):
            member = member.__func__
        elif isinstance(member, property):
            member = member.fget
        if inspect.isfunction(member):
            yield name, member


def public_functions(module: ModuleType) -> Iterator[tuple[str, Callable]]:
    """(qualified name, function) of the module's public functions and its public classes' methods."""
    for name, member in vars(module).items():
        if name.startswith("_"):
            continue
        function = inspect.unwrap(member) if callable(member) else member
        if inspect.isfunction(function) and function.__module__ == module.__name__:
            yield f"{module.__name__}.{name}", function
        elif inspect.isclass(member) and member.__module__ == module.__name__:
            for method_name, method in class_functions(member):
                yield f"{module.__name__}.{name}.{method_name}", method


def unannotated(function: Callable) -> list[str]:
    """The parameters of `function` (but self, cls) without an annotation, and 'return' if it lacks one."""
    signature = inspect.signature(function)
    missing = [
        p.name
        for p in signature.parameters.values()
        if p.name not in ("self", "cls") and p.annotation is inspect.Parameter.empty
    ]
    if signature.return_annotation is inspect.Signature.empty:
        missing.append("return")
    return missing


def test_the_check_finds_a_missing_annotation():
    def annotated(x: int, *args: float, **kwargs: str) -> None: ...

    def bare(self, x, y: int = 1, *args, **kwargs): ...

    assert unannotated(annotated) == []
    assert unannotated(bare) == ["x", "args", "kwargs", "return"]


def test_every_public_function_is_annotated():
    checked, missing = 0, []
    for module in public_modules():
        for name, function in public_functions(module):
            checked += 1
            lacking = unannotated(function)
            if lacking:
                missing.append(f"{name}({', '.join(lacking)})")
    assert checked > 300, f"only {checked} public functions found: the walk over the packages is broken"
    assert not missing, f"{len(missing)} public functions lack type hints:\n" + "\n".join(missing)
