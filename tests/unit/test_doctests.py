"""Every example in a docstring of the package, the DBC package and the emulator runs as shown."""

import doctest
import importlib
import pkgutil

import pytest

import canfdi


def _modules():
    names = ["canfdi.dbc"]
    for package in (canfdi,):  # canfdi.firmware_sim included
        names += [m.name for m in pkgutil.walk_packages(package.__path__, f"{package.__name__}.")
                  if not m.name.endswith("__main__")]
    return sorted(names)


@pytest.mark.parametrize("name", _modules())
def test_docstring_examples(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
