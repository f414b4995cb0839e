//! The covisibility graph of the cameras and its spanning tree from the reference.

use std::collections::VecDeque;

use crate::CalibError;

/// One tree node: the camera, its parent (`None` for the reference) and the shared view ids.
pub(crate) type TreeNode = (usize, Option<usize>, Vec<u64>);

/// Per camera, the view ids with a board pose. Returns, in BFS order from `reference`,
/// `(camera, parent, shared view ids)` (the reference has parent `None`), or
/// [`CalibError::NotConnected`] naming the groups of cameras that share no view.
pub(crate) fn spanning_tree(
    names: &[String],
    views: &[Vec<u64>],
    reference: usize,
) -> Result<Vec<TreeNode>, CalibError> {
    let n = names.len();
    let shared = |a: usize, b: usize| -> Vec<u64> {
        views[a].iter().copied().filter(|v| views[b].contains(v)).collect()
    };
    let mut seen = vec![false; n];
    let mut order = Vec::new();
    let mut queue = VecDeque::from([reference]);
    seen[reference] = true;
    order.push((reference, None, Vec::new()));
    while let Some(a) = queue.pop_front() {
        // The neighbour with the most shared views first (the strongest edge).
        let mut next: Vec<(usize, Vec<u64>)> =
            (0..n).filter(|&b| !seen[b]).map(|b| (b, shared(a, b))).collect();
        next.retain(|(_, s)| !s.is_empty());
        next.sort_by_key(|(_, s)| std::cmp::Reverse(s.len()));
        for (b, s) in next {
            if !seen[b] {
                seen[b] = true;
                order.push((b, Some(a), s));
                queue.push_back(b);
            }
        }
    }
    if order.len() == n {
        return Ok(order);
    }
    // Connected components, for the message.
    let mut comp = vec![usize::MAX; n];
    let mut groups: Vec<Vec<String>> = Vec::new();
    for s in 0..n {
        if comp[s] != usize::MAX {
            continue;
        }
        let g = groups.len();
        let mut q = VecDeque::from([s]);
        comp[s] = g;
        let mut members = Vec::new();
        while let Some(a) = q.pop_front() {
            members.push(names[a].clone());
            for (b, cb) in comp.iter_mut().enumerate() {
                if *cb == usize::MAX && !shared(a, b).is_empty() {
                    *cb = g;
                    q.push_back(b);
                }
            }
        }
        groups.push(members);
    }
    Err(CalibError::NotConnected {
        groups: groups
            .iter()
            .map(|g| format!("{{{}}}", g.join(", ")))
            .collect::<Vec<_>>()
            .join(" and "),
    })
}
