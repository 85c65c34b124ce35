"""taichi_hair.source_positions: Taichi's source diagrams made only for error messages. Kernels
compile and run as before, and a kernel with an error still names its line with a caret
under the offending code."""

import pytest
import taichi as ti

from taichi_hair import runtime, source_positions


def test_kernels_run_and_errors_keep_their_caret_diagram():
    runtime.ensure_init()
    from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext
    assert source_positions.install()
    assert ASTTransformerContext.get_pos_info.full_text is not None  # installed by init

    out = ti.field(float, shape=4)

    @ti.kernel
    def fill(scale: float):
        for i in out:
            out[i] = scale * i

    fill(2.0)
    assert list(out.to_numpy()) == [0.0, 2.0, 4.0, 6.0]

    @ti.kernel
    def broken():
        for i in out:
            out[i] = no_such_name_anywhere * 2.0  # noqa: F821

    with pytest.raises(ti.TaichiCompilationError) as raised:
        broken()
    message = str(raised.value)
    assert "no_such_name_anywhere" in message
    lines = message.splitlines()
    source = next(k for k, line in enumerate(lines) if "out[i] = no_such_name_anywhere * 2.0" in line)
    assert set(lines[source + 1].strip()) == {"^"}  # the diagram under the line, as Taichi makes it
