"""What runs after a study's cases: a post-processor named by ``[study] post = "<name>"`` (the stability map, say).

A post-processor is registered with its options' table and their reader::

    @register_post("stability_map", table="map", check=map_config)
    def _map(summary: pd.DataFrame, study: Study, folder: Path, config: MapConfig, executor: Executor) -> None: ...

- ``table``: the study's sub-table holding its options (``"map"``: ``[study.map]``), allowed in a study file only when
  its ``post`` names this post-processor; absent, ``check`` gets an empty table;
- ``check(table, where) -> config``: reads the options when the study file is read (``where``: the study file);
  a ``ValueError`` whose message names the key (``"[study.map].growth = ...: ..."``, optionally after ``where: ``)
  becomes a :class:`~milling_twin.orchestrator.study.spec.StudyError` naming the file and that key;
- the function: called by ``sweep`` on the command's process after the summary is written (``summary``: the
  consolidated summary, failed rows included; ``folder``: ``<out>/<study name>/``, where its files go; ``executor``:
  the study's executor, still open, for work of its own that parallelises). It may print what a reader of the
  command wants to see;
- ``prepare(study, config, executor) -> prepared`` (optional): called when the executor opens, before the cases,
  for work that needs no case (submitted with :func:`~milling_twin.orchestrator.study.executor.submit_in_background`, it
  fills the workers' idle moments); the function then gets its result as a sixth argument.

Modules that register one are listed in :data:`milling_twin.orchestrator.study.reduce.PLUGIN_MODULES` (imported on
demand, as for reductions).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any

__all__ = ["POSTS", "PostProcess", "get_post", "register_post"]


@dataclass(frozen=True)
class PostProcess:
    name: str
    table: str  # the [study.<table>] of its options
    check: Callable[[Mapping[str, Any], str], Any]  # (table, where) -> config
    run: Callable[..., Any]  # run(summary, study, folder, config, executor[, prepared])
    prepare: Callable[..., Any] | None = None  # prepare(study, config, executor) -> prepared, before the cases


POSTS: dict[str, PostProcess] = {}


def register_post(name: str, *, table: str, check: Callable[[Mapping[str, Any], str], Any],
                  prepare: Callable[..., Any] | None = None) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """Decorator registering ``fn(summary, study, folder, config, executor)`` as the post-processor ``name``; with
    ``prepare``, ``fn(summary, study, folder, config, executor, prepared)``."""
    def add(fn: Callable[..., Any]) -> Callable[..., Any]:
        POSTS[name] = PostProcess(name, table, check, fn, prepare)
        return fn
    return add


def get_post(name: str) -> PostProcess:
    """The post-processor ``name`` (importing the plugin modules first if needed); KeyError naming the known ones."""
    if name not in POSTS:
        from milling_twin.orchestrator.study.reduce import import_plugins

        import_plugins()
    if name not in POSTS:
        known = ", ".join(sorted(POSTS)) or "none registered"
        raise KeyError(f"unknown post-processor {name!r}; known: {known}")
    return POSTS[name]
