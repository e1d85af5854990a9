"""A plugin whose import raises: the config check must refuse it in one line."""

raise RuntimeError("this plugin cannot be set up here")
