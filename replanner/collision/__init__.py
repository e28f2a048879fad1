"""The collision room: one `Checker` interface over a robot in its world. The exact checker (FCL behind a compiled
broadphase, self-clearance tables and sweep bounds) has the last word; the fast layer (collision.fast) answers what
it can for certain in front of it."""

from .exact import OCTREE, BodyPoses, Clearance, CollisionChecker, Contact, ContactKind, PathCheck

__all__ = ["OCTREE", "BodyPoses", "Clearance", "CollisionChecker", "Contact", "ContactKind", "PathCheck"]
