"""Importing this module warms the process as the local pool's fork server
(:func:`vdc.warm.warm_fork_server`): the standard library's fork server can only import the
modules of its preload list, so ``vdc.pool_workers.WARM_PRELOAD`` names this one. Nothing
else imports it."""

from __future__ import annotations

from vdc.warm import warm_fork_server

warm_fork_server()
