"""rodo.estimator's __init__ is a map of the package: every public name resolves to the object its module
defines, and every public module of the package contributes to the map."""

import importlib
import pkgutil

import rodo.estimator as estimator


def test_every_exported_name_resolves_to_its_modules_object():
    for name in estimator.__all__:
        module = importlib.import_module(f"rodo.estimator.{estimator._WHERE[name]}")
        assert getattr(estimator, name) is getattr(module, name), name


def test_every_public_module_is_in_the_map():
    kernels = {"motion_kernels", "measurement_kernels", "association_kernels", "prepare_kernels", "doppler_kernels",
               "window_kernels", "map_kernels", "matching_kernels", "uncertainty_kernels",
               "jit"}  # compiled
    modules = {m.name for m in pkgutil.iter_modules(estimator.__path__)
               if not m.name.startswith("_") and m.name not in kernels}
    listed = set(estimator._EXPORTS) | {"measurements"}  # the NumPy reference, used as a module
    assert modules <= listed, sorted(modules - listed)
