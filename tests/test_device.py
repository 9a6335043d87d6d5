"""panorecon.device: the MKL VML warm-up that keeps a run's first parallel unary ops at full accuracy."""

import subprocess
import sys

import torch

from panorecon import device


def test_every_vml_op_is_a_torch_function_that_keeps_a_float_dtype():
    assert {"exp", "log", "sqrt", "sin", "cos", "tanh"} <= set(device.VML_OPS)  # what the pipeline runs on big tensors
    for op in device.VML_OPS:
        for dtype in (torch.float32, torch.float64):
            assert getattr(torch, op)(torch.full((1,), 0.5, dtype=dtype)).dtype == dtype, op


def test_the_warm_up_calls_each_vml_op_on_one_element_of_each_float_dtype(monkeypatch):
    calls = []
    for op in device.VML_OPS:
        real = getattr(torch, op)
        monkeypatch.setattr(
            torch, op, lambda x, _op=op, _real=real: calls.append((_op, x.dtype, x.numel())) or _real(x)
        )
    device.warm_up_vml()
    expected = {(op, dtype, 1) for op in device.VML_OPS for dtype in (torch.float32, torch.float64)}
    assert set(calls) == expected and len(calls) == len(expected)


def test_importing_the_module_warms_up_before_anything_else_runs():
    """In a fresh interpreter, torch.exp is seen on one float32 and one float64 element while panorecon.device
    is imported: the kernels are picked before a caller's first parallel op."""
    code = (
        "import torch\n"
        "seen = []\n"
        "real = torch.exp\n"
        "torch.exp = lambda x: seen.append((x.dtype, x.numel())) or real(x)\n"
        "import panorecon.device\n"
        "print(sorted(str(d) for d, n in seen if n == 1))\n"
    )
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "['torch.float32', 'torch.float64']"
