"""The browser workbench (``l2e-studio [--scenes DIR]``): a viser app over the engine.

Only this package imports viser; the engine never imports it. Entry points:
:func:`l2e_studio.app.server.build_app` and :func:`l2e_studio.app.server.serve`.
"""
