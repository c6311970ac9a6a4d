"""The live loop behind `torchik live`: samples from a source (torchik/live/) tracked as they come,
every character one row of a batch, the estimates published as they are made (LSL outlets, a
rerun viewer, a robot retargeted to as it goes).

mailbox: the samples between the receiver and the tracking loop, and how many of them the loop
catches up; loop: the loop itself (`track_live`); targets: which segments are the tracked links,
and the batch's targets of a step; batch: the tracker of the active characters, and the robot
(`LiveRetarget`); history: what a session keeps and gives back (`LiveResult`); publish: the LSL
outlets; viewer: the rerun viewer.
"""

from .batch import BatchTracker, LiveRetarget
from .history import History, LiveResult
from .loop import LiveOptions, track_live
from .mailbox import CatchUp, Mailbox
from .publish import Publisher
from .targets import Selection, sample_targets

__all__ = ["BatchTracker", "CatchUp", "History", "LiveOptions", "LiveResult", "LiveRetarget", "Mailbox", "Publisher",
           "Selection", "sample_targets", "track_live"]
