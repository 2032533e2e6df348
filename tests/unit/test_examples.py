"""Every public class of core, bus and methods carries a doctested Examples section (the
conventions of DESIGN.md); tests/unit/test_doctests.py runs them."""

import importlib
import inspect
import pkgutil

import pytest

import canfdi.bus
import canfdi.core
import canfdi.methods

PACKAGES = (canfdi.core, canfdi.bus, canfdi.methods)


def _public_classes():
    for package in PACKAGES:
        names = [package.__name__] + [m.name for m in pkgutil.walk_packages(
            package.__path__, f"{package.__name__}.")]
        for name in sorted(names):
            if any(part.startswith("_") for part in name.split(".")):
                continue
            module = importlib.import_module(name)
            public = getattr(module, "__all__", None)
            for attr, obj in sorted(vars(module).items()):
                if (inspect.isclass(obj) and obj.__module__ == name and not attr.startswith("_")
                        and (public is None or attr in public)):
                    yield f"{name}.{attr}", obj


CLASSES = dict(_public_classes())


def test_the_walk_finds_the_classes():
    assert len(CLASSES) > 80
    assert "canfdi.core.detect.ChangePointDetector" in CLASSES


@pytest.mark.parametrize("name", sorted(CLASSES))
def test_public_class_has_a_doctested_example(name):
    doc = inspect.getdoc(CLASSES[name]) or ""
    assert "Examples\n--------" in doc and ">>> " in doc, f"{name}: no doctested Examples"
