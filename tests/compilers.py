"""Whether TorchInductor has a compiler here: the tests that compile skip only where it has none,
and fail where a capture fails with a compiler present (the code or the set-up is then to mend)."""

import shutil


def missing_compiler(device: str) -> str | None:
    """Why TorchInductor has no compiler for `device` on this machine, or None where it has one."""
    if device == "cuda":
        from torch.utils._triton import has_triton

        return None if has_triton() else "Triton is not installed"
    from torch._inductor import cpp_builder

    try:
        compiler = cpp_builder.get_cpp_compiler()
    except Exception as error:  # noqa: BLE001 - whatever stops TorchInductor finding one
        return f"no C++ compiler ({error})"
    return None if shutil.which(compiler) else f"no C++ compiler ({compiler} not found)"
