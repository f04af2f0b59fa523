//! ntg-trainer (wip)
