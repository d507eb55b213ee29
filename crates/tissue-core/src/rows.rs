//! Variable-length rows made in parallel, joined into one CSR.

use rayon::prelude::*;

/// Items per block of [`rows_in_blocks`]' parallel loop.
const BLOCK: usize = 128;

/// Rows `0..count` in CSR, `(offsets, entries)`: row `i` is
/// `entries[offsets[i]..offsets[i + 1]]` (`per_row` entries expected of
/// each, room made for them beforehand), made by `row(scratch, i, out)`
/// appending its entries to `out`. The rows are made a block at a time in
/// parallel, each block's rows in one buffer with one `scratch` (from
/// `scratch()`), then joined in order: an allocation per row would have the
/// threads queue on the allocator's lock. The result does not depend on the
/// thread count.
pub fn rows_in_blocks<S, T: Copy + Send + Sync>(
    count: usize,
    per_row: usize,
    scratch: impl Fn() -> S + Sync,
    row: impl Fn(&mut S, usize, &mut Vec<T>) + Sync,
) -> (Vec<u32>, Vec<T>) {
    let blocks: Vec<(Vec<u32>, Vec<T>)> = (0..count.div_ceil(BLOCK))
        .into_par_iter()
        .map(|b| {
            let items = b * BLOCK..((b + 1) * BLOCK).min(count);
            let mut state = scratch();
            let mut lengths = Vec::with_capacity(items.len());
            let mut entries = Vec::with_capacity(per_row * items.len());
            for i in items {
                let first = entries.len();
                row(&mut state, i, &mut entries);
                lengths.push((entries.len() - first) as u32);
            }
            (lengths, entries)
        })
        .collect();
    let mut offsets = Vec::with_capacity(count + 1);
    offsets.push(0u32);
    let mut entries = Vec::with_capacity(blocks.iter().map(|(_, e)| e.len()).sum());
    for (lengths, block) in blocks {
        for length in lengths {
            offsets.push(offsets[offsets.len() - 1] + length);
        }
        entries.extend_from_slice(&block);
    }
    (offsets, entries)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rows_are_joined_in_order_across_blocks() {
        // Row i holds i % 5 copies of i, with rows spanning many blocks.
        let (offsets, entries) = rows_in_blocks(
            1000,
            2,
            || 0usize,
            |made, i, out| {
                *made += 1;
                out.extend(std::iter::repeat_n(i as u32, i % 5));
            },
        );
        assert_eq!(offsets.len(), 1001);
        for i in 0..1000 {
            let row = &entries[offsets[i] as usize..offsets[i + 1] as usize];
            assert_eq!(row.len(), i % 5, "row {i}");
            assert!(row.iter().all(|&e| e == i as u32), "row {i}");
        }
        let (offsets, entries) = rows_in_blocks::<(), u32>(0, 0, || (), |_, _, _| {});
        assert_eq!((offsets, entries), (vec![0], vec![]));
    }
}
