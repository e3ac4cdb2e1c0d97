"""How a fill runs, apart from what it computes (see DESIGN.md); one home each:

* :mod:`.cache` -- results kept by a fingerprint of their inputs (a repeat is a lookup), all
  forgotten at once between the windows of a long recording;
* :mod:`.threads` -- independent pieces of work in threads that share torch's threads out;
* :mod:`.memory` -- the heap's free pages handed back to the system between a fill's stages.

Nothing here imports another torchfill module; importing the package imports no torch.
"""
