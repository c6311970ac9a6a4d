"""pipelines.roofline: flops and bytes counted from the shapes as documented, every operation of a
step charged to one phase, and `torchik bench --profile` printing the table."""

import torch

from torchik.cli import main
from torchik.pipelines import roofline


def counted(call) -> roofline.Phase:
    """The totals of the operations `call` runs (charged to 'other': no phase function calls them)."""
    counter = roofline._Counter({})
    with counter:
        call()
    return counter.phases["other"]


def test_a_matrix_product_counts_2mnk_flops_and_its_three_matrices_bytes():
    a, b = torch.randn(4, 5, dtype=torch.float64), torch.randn(5, 6, dtype=torch.float64)
    totals = counted(lambda: torch.mm(a, b))
    assert totals.flops == 2 * 4 * 5 * 6
    assert totals.bytes == 8 * (4 * 5 + 5 * 6 + 4 * 6)


def test_elementwise_ops_count_one_flop_per_element_and_addcmul_two():
    x, y = torch.randn(100, dtype=torch.float64), torch.randn(100, dtype=torch.float64)
    assert counted(lambda: x + y).flops == 100
    assert counted(lambda: torch.addcmul(x, x, y)).flops == 200
    assert counted(lambda: x.sum()).flops == 100


def test_views_move_nothing_and_gathers_only_what_they_select():
    x = torch.randn(1000, 3, dtype=torch.float64)
    view = counted(lambda: x.T)
    assert view.bytes == 0 and view.flops == 0 and view.operations == 1
    index = torch.tensor([1, 2])
    gather = counted(lambda: x.index_select(0, index))
    assert gather.bytes == 2 * (2 * 3 * 8) + 2 * 8  # read and write the 2 rows, read the index


def test_a_broadcast_operand_counts_its_stored_elements():
    x, row = torch.randn(1000, 3, dtype=torch.float64), torch.randn(3, dtype=torch.float64)
    totals = counted(lambda: x * row.expand(1000, 3))
    assert totals.bytes == 8 * (3000 + 3 + 3000)


def test_cholesky_counts_n_cubed_over_three_per_matrix():
    A = torch.eye(6, dtype=torch.float64).expand(10, 6, 6).clone()
    assert counted(lambda: torch.linalg.cholesky_ex(A)).flops == 10 * 6 ** 3 / 3


def test_every_operation_of_a_step_is_charged_to_a_phase_of_the_step():
    peaks = roofline.Peaks(1.0, 1.0)  # not measured: this test reads the counts only
    result = roofline.profile("human48", 16, steps=2, warmup=2, peaks=peaks)
    names = [p.name for p in result.phases]
    assert {"kinematics", "normal equations", "qp: factorisation", "qp: solves", "integration"} <= set(names)
    assert names == [name for name in roofline.ORDER if name in names]  # in the step's order
    assert all(p.operations > 0 and p.seconds > 0 for p in result.phases)
    kinematics = result.phases[names.index("kinematics")]
    assert kinematics.flops > 0 and kinematics.bytes > kinematics.flops  # memory-bound: below one flop per byte
    assert "qp: factorisation" in roofline.table(result)


def test_bench_profile_prints_the_roofline_after_the_table(capsys):
    assert main(["bench", "--models", "human48", "--batch", "8", "--no-loops", "--quiet", "--profile",
                 "--max-steps", "3", "--seconds", "0.2"]) == 0
    out = capsys.readouterr().out
    assert "subject-steps/s" in out and "GFLOP/s (float64 matmul)" in out and "kinematics" in out
