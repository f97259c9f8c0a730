"""The workbench's GUI panels, one module each. Each builds its widgets in ``__init__``
(inside whatever viser container is current) and exposes ``show_*`` methods that the server
calls to refresh them from the shared state. A panel sees the app only through
:class:`~l2e_studio.app.context.Workbench` and never imports :mod:`l2e_studio.app.server`."""
