"""Taichi's source positions made only when an error needs them.

Taichi 1.7 turns every kernel's Python into its IR each time a process first calls it (also
when the offline cache then finds the kernel compiled), and for every statement and expression
on the way it writes the source line with a caret diagram under it (`get_pos_info`, through
`textwrap`): the text an error message would show. Measured on a warm start of the main job
(`taichi-hair run scenes/wind_straight.py --frames 1`, 2 cores): 44 s to the first frame, 35 s
with the diagram made only for errors. `install` keeps the diagram for every error (Taichi asks
for it inside its exception handler) and gives the statements being built a one-line position
("File ..., line ..., in ...") instead.
"""

import sys


def install() -> bool:
    """Replace Taichi's position text by `position_text` (once per process); False (and nothing
    replaced) where this Taichi has no `ASTTransformerContext.get_pos_info` to replace."""
    try:
        from taichi.lang.ast.ast_transformer_utils import ASTTransformerContext
    except ImportError:
        return False
    full = getattr(ASTTransformerContext, "get_pos_info", None)
    if full is None:
        return False
    if getattr(full, "full_text", None) is not None:
        return True  # installed already

    def position_text(ctx, node) -> str:
        """The caret diagram while an exception is being handled (an error message), else the
        file, line and function of `node` only."""
        if sys.exc_info()[0] is not None:
            return full(ctx, node)
        return f'File "{ctx.file}", line {node.lineno + ctx.lineno_offset}, in {ctx.func.func.__name__}:\n'

    position_text.full_text = full
    ASTTransformerContext.get_pos_info = position_text
    return True
