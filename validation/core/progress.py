"""Progress bars for long work (tqdm on stderr), handed to :mod:`gp_model` as callbacks so the
maths stays free of user-interface imports."""
from __future__ import annotations

from contextlib import contextmanager


@contextmanager
def progress_bar(description: str, *, enabled: bool = True, total: int | None = None, unit: str = "step"):
    """Yield ``update(n, **status)`` that advances a tqdm bar by ``n`` and shows ``status`` (at
    once when ``n`` is 0: a status within a step); yields None when ``enabled`` is False. The bar
    is closed (and erased) on exit."""
    if not enabled:
        yield None
        return
    from tqdm.auto import tqdm

    bar = tqdm(total=total, desc=description, unit=unit, leave=False)

    def update(n: int, **status) -> None:
        bar.update(n)
        if status:
            bar.set_postfix(status, refresh=n == 0)

    try:
        yield update
    finally:
        bar.close()
