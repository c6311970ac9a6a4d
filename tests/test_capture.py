"""capture: while it compiles, TorchInductor's notices that an operation has no C shim (called
through the dispatcher instead, nothing a user can act on) are dropped, its other messages kept,
and the logger is as it was afterwards; options this torch lacks are not asked for."""

import logging

from torchik.method.capture import _quiet_fallbacks

NOTICE = "%s is missing a c-shim implementation, using proxy executor as fallback"  # TorchInductor's wording


def test_no_shim_notices_are_dropped_while_compiling_and_other_messages_kept(caplog):
    logger = logging.getLogger("torch._inductor.ir")
    with caplog.at_level(logging.WARNING, logger="torch._inductor.ir"):
        with _quiet_fallbacks():
            logger.warning(NOTICE, "aten.linalg_cholesky_ex.default")
            logger.warning("another warning")
        logger.warning(NOTICE, "aten.linalg_solve_triangular.default")
    messages = [record.getMessage() for record in caplog.records]
    assert messages == ["another warning", NOTICE % "aten.linalg_solve_triangular.default"]


def test_fused_multiply_adds_are_asked_for_only_where_this_torch_has_the_option(monkeypatch):
    """An option this torch does not know would fail the whole capture: it is left out there."""
    from torch._inductor import config

    from torchik.method.capture import _contraction

    with config.patch(_contraction()):  # this torch takes what is asked for
        pass
    monkeypatch.delattr(config.cpp, "enable_floating_point_contract_flag", raising=False)
    assert _contraction() == {}
