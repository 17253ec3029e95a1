"""The run: the stage that owns a job from its inputs to its folder.

`original` (the cached original avatar), `folder` (the run folder's one writer and one reader:
the only code that knows its file names), `outputs` (grid, video, avatar files), `job` (the
main job: edit, outputs, evaluation), and for studies `bench` (many variants in one process),
`oracle` (editors that read the ideal edit: studies only) and `scenarios` (the claims' scenes).
"""
