"""Jobs built from the layers below: the demo (:mod:`.demo`) and the scheduling of training runs
as parallel processes within a time budget (:mod:`.schedule`)."""
