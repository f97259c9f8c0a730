"""The workbench's GUI panels, one module each. Each builds its widgets in ``__init__``
(inside whatever viser container is current) and exposes ``show_*`` methods that the
:class:`~l2e_studio.app.server.App` calls to refresh them from the shared state."""
