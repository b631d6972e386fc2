//! Residency of the streamed arrays: which prefix of each cell's triangles and points is on the
//! GPU, where, and what to upload or evict next. Pure bookkeeping, no GPU types, so it is tested
//! on the CPU; the renderer carries out the uploads it plans.
//!
//! Triangles and points of every model share one pool buffer, allocated in units of 48 bytes (one
//! point record, or two triangle records), so the pool can be bound both as an array of triangles
//! and as an array of points. Each (model, cell, kind) owns at most one slot of the pool, holding a
//! prefix of the cell's size-sorted range: the coarsest records first, so any prefix is a valid
//! coarser level of detail (spec §10). A slot's capacity is a power of two units, so a prefix that
//! keeps growing is moved `O(log n)` times. Every model's roots (the first points of every cell,
//! `ModelLod::roots`) are copied into one pinned slot when the model is added: a cell with nothing
//! resident still draws its roots, never a hole.

use std::collections::BTreeMap;

/// Bytes per pool unit: one `PointRecord`, two `TriangleRecord`s.
pub(crate) const UNIT: u64 = 48;
/// Bytes of one triangle record.
pub(crate) const TRIANGLE_BYTES: u64 = 24;

/// Which streamed array.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) enum Array {
    Triangles = 0,
    Points = 1,
}

impl Array {
    /// Pool units that hold `records` records.
    pub(crate) fn units(self, records: u32) -> u32 {
        match self {
            Self::Triangles => records.div_ceil(2),
            Self::Points => records,
        }
    }

    /// Records that `units` units hold.
    pub(crate) fn records(self, units: u32) -> u32 {
        match self {
            Self::Triangles => units.saturating_mul(2),
            Self::Points => units,
        }
    }

    /// Bytes of one record.
    pub(crate) fn record_bytes(self) -> u64 {
        match self {
            Self::Triangles => TRIANGLE_BYTES,
            Self::Points => UNIT,
        }
    }
}

/// First-fit allocator of pool units, with coalescing free ranges.
#[derive(Debug)]
pub(crate) struct Pool {
    /// Units the pool buffer holds now.
    capacity: u32,
    /// Units it may grow to (the memory budget).
    max: u32,
    /// Free ranges: start → length, disjoint, not adjacent.
    free: BTreeMap<u32, u32>,
    used: u32,
}

impl Pool {
    /// An empty pool of `capacity` units that may grow to `max`.
    pub(crate) fn new(capacity: u32, max: u32) -> Self {
        let capacity = capacity.min(max);
        let mut free = BTreeMap::new();
        if capacity > 0 {
            free.insert(0, capacity);
        }
        Self { capacity, max, free, used: 0 }
    }

    pub(crate) fn capacity(&self) -> u32 {
        self.capacity
    }

    /// Units the pool may grow to.
    pub(crate) fn max(&self) -> u32 {
        self.max
    }

    pub(crate) fn used(&self) -> u32 {
        self.used
    }

    /// Allocates `units` contiguous units, growing the pool (doubling, up to `max`) if no free
    /// range is large enough; `None` if even the largest pool has no room.
    pub(crate) fn alloc(&mut self, units: u32) -> Option<u32> {
        if units == 0 {
            return Some(0);
        }
        loop {
            if let Some((&start, &len)) = self.free.iter().find(|&(_, &len)| len >= units) {
                self.free.remove(&start);
                if len > units {
                    self.free.insert(start + units, len - units);
                }
                self.used += units;
                return Some(start);
            }
            if self.capacity >= self.max {
                return None;
            }
            let grown = self.capacity.saturating_mul(2).max(self.capacity.saturating_add(units)).min(self.max);
            let (old, added) = (self.capacity, grown - self.capacity);
            self.capacity = grown;
            self.free_range(old, added);
        }
    }

    /// Returns `units` units at `start` to the pool.
    pub(crate) fn free(&mut self, start: u32, units: u32) {
        if units > 0 {
            self.used -= units;
            self.free_range(start, units);
        }
    }

    fn free_range(&mut self, mut start: u32, mut units: u32) {
        if let Some((&before, &len)) = self.free.range(..start).next_back()
            && before + len == start
        {
            self.free.remove(&before);
            start = before;
            units += len;
        }
        if let Some(&len) = self.free.get(&(start + units)) {
            self.free.remove(&(start + units));
            units += len;
        }
        self.free.insert(start, units);
    }
}

/// The resident prefix of one (model, cell, kind).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct Slot {
    /// First pool unit.
    pub(crate) start: u32,
    /// Units owned (0: no slot).
    pub(crate) units: u32,
    /// Leading records of the cell's range that are on the GPU.
    pub(crate) resident: u32,
    /// Last frame that asked for this slot's data.
    pub(crate) last_needed: u64,
}

/// One copy the renderer makes: `count` records of `array`, starting at record `first` of the
/// model's container array, to byte `offset` of the pool.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub(crate) struct Upload {
    pub(crate) model: usize,
    pub(crate) array: Array,
    pub(crate) first: u32,
    pub(crate) count: u32,
    pub(crate) offset: u64,
}

/// One request of a frame: the leading `wanted` records of a cell's range, which starts at record
/// `first` of the container array.
#[derive(Clone, Copy, Debug)]
pub(crate) struct Request {
    pub(crate) model: usize,
    pub(crate) cell: usize,
    pub(crate) array: Array,
    pub(crate) first: u32,
    pub(crate) wanted: u32,
}

/// Counters of one [`Residency::stream`].
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub(crate) struct StreamStats {
    pub(crate) bytes_uploaded: u64,
    pub(crate) evicted_units: u64,
    /// Requests left short (budget or memory).
    pub(crate) short: u32,
}

/// Slots of every model's cells, and the pool they live in.
#[derive(Debug)]
pub(crate) struct Residency {
    pub(crate) pool: Pool,
    /// Per model, per cell index: triangle and point slots.
    slots: Vec<Vec<[Slot; 2]>>,
    frame: u64,
}

impl Residency {
    pub(crate) fn new(pool: Pool) -> Self {
        Self { pool, slots: Vec::new(), frame: 0 }
    }

    /// Registers a model of `cells` cells; returns the pool unit of a pinned slot of `pinned`
    /// points (the model's roots), or `None` if the pool cannot hold it.
    pub(crate) fn add_model(&mut self, cells: usize, pinned: u32) -> Option<u32> {
        let start = self.alloc_evicting(pinned, &mut StreamStats::default())?;
        self.slots.push(vec![[Slot::default(); 2]; cells]);
        Some(start)
    }

    /// The slot of a cell.
    pub(crate) fn slot(&self, model: usize, cell: usize, array: Array) -> Slot {
        self.slots.get(model).and_then(|m| m.get(cell)).map_or_else(Slot::default, |s| s[array as usize])
    }

    /// Starts a frame: requests from now on count as needed in it.
    pub(crate) fn begin_frame(&mut self) {
        self.frame += 1;
    }

    /// Marks a request as needed this frame (so it is not evicted to make room for others).
    pub(crate) fn touch(&mut self, request: &Request) {
        if let Some(slot) = self.slots.get_mut(request.model).and_then(|m| m.get_mut(request.cell)) {
            slot[request.array as usize].last_needed = self.frame;
        }
    }

    /// Grows resident prefixes towards `requests` (each touched first) within `budget` bytes of
    /// uploads, emptiest first (a cell with nothing resident before one that is nearly complete),
    /// evicting the finest halves of slots not needed this frame, least recently needed first,
    /// when the pool is full. Returns the uploads to make, in order.
    pub(crate) fn stream(&mut self, requests: &mut [Request], budget: u64, uploads: &mut Vec<Upload>) -> StreamStats {
        let mut stats = StreamStats::default();
        for request in requests.iter() {
            self.touch(request);
        }
        // Emptiest first: by resident fraction, then by model and cell for determinism.
        let resident = |s: &Self, r: &Request| u64::from(s.slot(r.model, r.cell, r.array).resident);
        requests.sort_by(|a, b| {
            let (ra, rb) = (resident(self, a) * u64::from(b.wanted), resident(self, b) * u64::from(a.wanted));
            ra.cmp(&rb).then((a.model, a.cell, a.array as u8).cmp(&(b.model, b.cell, b.array as u8)))
        });
        let mut left = budget;
        for request in requests.iter() {
            let slot = self.slot(request.model, request.cell, request.array);
            if slot.resident >= request.wanted {
                continue;
            }
            let array = request.array;
            let record = array.record_bytes();
            let affordable = u32::try_from(left / record).unwrap_or(u32::MAX);
            let mut slot = slot;
            let mut from = slot.resident;
            let target;
            if array.records(slot.units) >= request.wanted {
                target = request.wanted.min(slot.resident.saturating_add(affordable));
            } else {
                // Move to a larger slot (the resident part is uploaded again): one for the whole
                // request if the pool has room, else the largest power of two that fits, as long
                // as it is larger than the current slot. The coarsest records come first.
                let fits = affordable.min(request.wanted);
                if fits <= slot.resident {
                    stats.short += 1;
                    continue;
                }
                let mut units = array.units(request.wanted).next_power_of_two();
                let start = loop {
                    if units <= slot.units {
                        break None;
                    }
                    if let Some(start) = self.alloc_evicting(units, &mut stats) {
                        break Some(start);
                    }
                    units /= 2;
                };
                let Some(start) = start else {
                    // No room for more: the cell keeps what it has (or its pinned roots).
                    slot.last_needed = self.frame;
                    self.set(request, slot);
                    stats.short += 1;
                    continue;
                };
                self.pool.free(slot.start, slot.units);
                slot = Slot { start, units, resident: 0, last_needed: self.frame };
                from = 0;
                target = fits.min(array.records(units));
            }
            if target > from {
                let count = target - from;
                uploads.push(Upload {
                    model: request.model,
                    array,
                    first: request.first + from,
                    count,
                    offset: u64::from(slot.start) * UNIT + u64::from(from) * record,
                });
                let bytes = u64::from(count) * record;
                left = left.saturating_sub(bytes);
                stats.bytes_uploaded += bytes;
            }
            slot.resident = target;
            if target < request.wanted {
                stats.short += 1;
            }
            self.set(request, slot);
        }
        stats
    }

    fn set(&mut self, request: &Request, slot: Slot) {
        if let Some(s) = self.slots.get_mut(request.model).and_then(|m| m.get_mut(request.cell)) {
            s[request.array as usize] = slot;
        }
    }

    /// Allocates `units`, evicting (halving) slots not needed this frame, least recently needed
    /// first, until it fits or nothing is left to evict.
    fn alloc_evicting(&mut self, units: u32, stats: &mut StreamStats) -> Option<u32> {
        loop {
            if let Some(start) = self.pool.alloc(units) {
                return Some(start);
            }
            // The least recently needed slot not needed this frame, by (last_needed, model, cell).
            let mut victim: Option<(u64, usize, usize, usize)> = None;
            for (m, cells) in self.slots.iter().enumerate() {
                for (c, pair) in cells.iter().enumerate() {
                    for (a, slot) in pair.iter().enumerate() {
                        if slot.units > 0
                            && slot.last_needed < self.frame
                            && victim.is_none_or(|(last, ..)| slot.last_needed < last)
                        {
                            victim = Some((slot.last_needed, m, c, a));
                        }
                    }
                }
            }
            let (_, m, c, a) = victim?;
            let array = if a == 0 { Array::Triangles } else { Array::Points };
            let slot = &mut self.slots[m][c][a];
            // Drop the finest half: the prefix stays valid, only coarser.
            let keep = slot.units / 2;
            let freed = slot.units - keep;
            let start = slot.start + keep;
            slot.units = keep;
            slot.resident = slot.resident.min(array.records(keep));
            if keep == 0 {
                *slot = Slot { last_needed: slot.last_needed, ..Slot::default() };
            }
            self.pool.free(start, freed);
            stats.evicted_units += u64::from(freed);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn request(cell: usize, array: Array, wanted: u32) -> Request {
        Request { model: 0, cell, array, first: 1000 * cell as u32, wanted }
    }

    #[test]
    fn pool_allocates_first_fit_grows_and_coalesces() {
        let mut pool = Pool::new(4, 16);
        assert_eq!(pool.alloc(3), Some(0));
        assert_eq!(pool.alloc(3), Some(3), "grows to 8");
        assert_eq!(pool.capacity(), 8);
        assert_eq!(pool.alloc(11), None, "past the maximum");
        pool.free(0, 3);
        pool.free(3, 3);
        assert_eq!(pool.used(), 0);
        assert_eq!(pool.alloc(8), Some(0), "freed neighbours coalesce");
        assert_eq!(pool.alloc(8), Some(8), "grows to the maximum");
        assert_eq!(pool.alloc(1), None);
    }

    #[test]
    fn prefixes_grow_within_the_upload_budget_and_converge() {
        let mut r = Residency::new(Pool::new(64, 1 << 20));
        assert_eq!(r.add_model(2, 2), Some(0));
        let mut frames = 0;
        loop {
            r.begin_frame();
            let mut requests = [request(0, Array::Points, 100), request(1, Array::Triangles, 301)];
            let mut uploads = Vec::new();
            let stats = r.stream(&mut requests, 1000, &mut uploads);
            let bytes: u64 = uploads.iter().map(|u| u64::from(u.count) * u.array.record_bytes()).sum();
            assert_eq!(bytes, stats.bytes_uploaded);
            assert!(bytes <= 1000, "{bytes} bytes over the budget");
            for u in &uploads {
                let slot = r.slot(u.model, u.first as usize / 1000, u.array);
                // Every upload lands inside its slot, in record order.
                let begin = u64::from(slot.start) * UNIT;
                assert!(u.offset >= begin);
                assert!(u.offset + u64::from(u.count) * u.array.record_bytes() <= begin + u64::from(slot.units) * UNIT);
            }
            frames += 1;
            if stats.short == 0 {
                break;
            }
            assert!(frames < 100, "does not converge");
        }
        assert_eq!(r.slot(0, 0, Array::Points).resident, 100);
        assert_eq!(r.slot(0, 1, Array::Triangles).resident, 301);
        // 48·100 + 24·301 bytes, plus re-uploads when slots moved, at ≤ 1000 bytes a frame.
        assert!(frames >= 12, "{frames} frames");
    }

    #[test]
    fn a_full_pool_evicts_the_finest_data_of_the_least_recently_needed_cells() {
        // 2 pinned + 3 cells of 32 points (32 units each) = 98 units; the pool holds 100.
        let mut r = Residency::new(Pool::new(100, 100));
        r.add_model(4, 2);
        for cell in 0..3 {
            r.begin_frame();
            let mut uploads = Vec::new();
            r.stream(&mut [request(cell, Array::Points, 32)], u64::MAX, &mut uploads);
            assert_eq!(r.slot(0, cell, Array::Points).resident, 32);
        }
        // Cell 3 needs 32 units: cell 0 (least recently needed) loses its finest half, then cell 1's.
        r.begin_frame();
        let mut uploads = Vec::new();
        let stats = r.stream(&mut [request(3, Array::Points, 32)], u64::MAX, &mut uploads);
        assert_eq!(r.slot(0, 3, Array::Points).resident, 32);
        assert_eq!(stats.short, 0);
        let (a, b, c) = (r.slot(0, 0, Array::Points), r.slot(0, 1, Array::Points), r.slot(0, 2, Array::Points));
        assert!(a.resident < 32, "the least recently needed cell shrank first: {a:?}");
        assert_eq!(c.resident, 32, "the most recently needed one kept its data: {c:?}");
        assert!(a.resident <= b.resident);
        assert!(r.pool.used() <= 100);
        // A cell needed in the same frame is never evicted for another.
        r.begin_frame();
        let mut requests =
            [request(3, Array::Points, 32), request(2, Array::Points, 32), request(0, Array::Points, 64)];
        r.stream(&mut requests, u64::MAX, &mut uploads);
        assert_eq!(r.slot(0, 3, Array::Points).resident, 32);
        assert_eq!(r.slot(0, 2, Array::Points).resident, 32);
    }

    #[test]
    fn a_request_larger_than_the_room_left_gets_the_coarsest_part_and_keeps_it() {
        let mut r = Residency::new(Pool::new(100, 100));
        r.add_model(2, 2);
        r.begin_frame();
        let mut uploads = Vec::new();
        let mut requests = [request(0, Array::Points, 64), request(1, Array::Points, 64)];
        let stats = r.stream(&mut requests, u64::MAX, &mut uploads);
        let (a, b) = (r.slot(0, 0, Array::Points), r.slot(0, 1, Array::Points));
        // 98 units free: one cell gets its 64, the other the largest power of two left, 32.
        assert_eq!((a.resident.max(b.resident), a.resident.min(b.resident)), (64, 32));
        assert_eq!(stats.short, 1);
        // Next frame the same requests move nothing: no upload is repeated.
        r.begin_frame();
        uploads.clear();
        let stats = r.stream(&mut requests, u64::MAX, &mut uploads);
        assert!(uploads.is_empty(), "{uploads:?}");
        assert_eq!((stats.short, stats.bytes_uploaded), (1, 0));
    }
}
