"""vdc's capture side: everything that produces a recording (simulated arena and robot, the
Colias serial link, the overhead tracker, and the Rerun recorder that alone knows the entity
paths and the blueprint)."""


def _check_vdc() -> None:
    """Stop at once, naming it, if ``import vdc`` finds another folder or file named ``vdc``
    (beside the user's script, say): otherwise the first ``vdc.`` name fails obscurely. The check
    is loaded by its path beside this package, since ``vdc.shadow`` may be what is hidden."""
    import importlib.util
    from pathlib import Path

    import vdc  # noqa: F401 - what it finds is what is checked

    path = Path(__file__).resolve().parent.parent / "vdc" / "shadow.py"
    spec = importlib.util.spec_from_file_location("_vdc_shadow_check", path)
    shadow = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(shadow)
    shadow.check_imported("vdc")


_check_vdc()
