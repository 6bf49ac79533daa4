"""The runtime type checker jaxtyping uses under pytest (see pyproject's `--jaxtyping-packages`).

beartype with PEP 484's implicit numeric tower, so an `int` is accepted where a `float` is
annotated (as type checkers do).
"""

from beartype import BeartypeConf, beartype

typechecker = beartype(conf=BeartypeConf(is_pep484_tower=True))
