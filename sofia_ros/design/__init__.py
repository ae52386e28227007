"""`sofia design`: the maneuvers that would tell a competing set's members apart (docs/design.md)."""
