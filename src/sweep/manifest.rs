//! The grid a sweep directory holds (`sweep.json`), written by every share of the sweep, so that
//! a report made later, from the logs alone, can name the variants that never produced one.

use super::{Sweep, SweepError};
use std::path::Path;

/// The grid's record in a sweep directory.
pub const MANIFEST_FILE: &str = "sweep.json";

impl Sweep {
    /// The grid recorded in `dir`, if any.
    pub fn read_manifest(dir: &Path) -> Result<Option<Self>, SweepError> {
        let path = dir.join(MANIFEST_FILE);
        let text = match std::fs::read_to_string(&path) {
            Ok(text) => text,
            Err(e) if e.kind() == std::io::ErrorKind::NotFound => return Ok(None),
            Err(e) => return Err(SweepError::Read { path, message: e.to_string() }),
        };
        serde_json::from_str(&text).map(Some).map_err(|e| SweepError::Read { path, message: format!("not a sweep record: {e}") })
    }

    /// Records this grid in `dir`. Shares of one sweep, written at the same time from several
    /// machines, find the record they would write; another grid is refused unless `replace`.
    pub(super) fn write_manifest(&self, dir: &Path, replace: bool) -> Result<(), SweepError> {
        let path = dir.join(MANIFEST_FILE);
        if let Some(existing) = Self::read_manifest(dir)? {
            if existing == *self {
                return Ok(());
            }
            if !replace {
                return Err(SweepError::OtherSweep { path, difference: existing.difference(self) });
            }
        }
        // Written aside and renamed, so that a reader never sees half a record.
        let nanos = std::time::SystemTime::now().duration_since(std::time::UNIX_EPOCH).map_or(0, |d| d.subsec_nanos());
        let aside = dir.join(format!(".{MANIFEST_FILE}.{}.{nanos}", std::process::id()));
        let text = serde_json::to_string_pretty(self).expect("a sweep serializes");
        std::fs::write(&aside, text + "\n").and_then(|()| std::fs::rename(&aside, &path)).map_err(|source| {
            let _ = std::fs::remove_file(&aside);
            SweepError::Write { path, source }
        })
    }

    /// What tells `self` (on disk) apart from `other`, in words.
    fn difference(&self, other: &Self) -> String {
        if self.scene != other.scene {
            format!("scene `{}`, not `{}`", self.scene.display(), other.scene.display())
        } else if self.sets != other.sets {
            format!("--set {:?}, not {:?}", self.sets, other.sets)
        } else {
            let over = |s: &Self| s.axes.iter().map(|a| format!("{}={}", a.key, a.values.join(","))).collect::<Vec<_>>().join(" ");
            format!("--over {}, not {}", over(self), over(other))
        }
    }
}
