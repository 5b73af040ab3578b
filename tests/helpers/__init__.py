"""What several test files share, so that no test file imports another (issue #20).

One module per subject: ``cli`` runs the command, ``staging`` reads what ``scene.atomic`` leaves in a directory,
``forests`` builds and probes instanced stages, ``crowns`` makes synthetic crowns of leaves.
"""
