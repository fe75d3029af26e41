//! Unit tests of `cache`.

mod tests {
    use cloudcontrol::cache::*;

    #[test]
    fn least_recently_used_entries_leave_first_and_the_bound_holds() {
        let mut c: Lru<u32, u32> = Lru::new(10);
        let mut load = |k: u32, w: u64| c.get_or_load(&k, || Ok::<_, ()>((k, w))).unwrap();
        load(1, 4);
        load(2, 4);
        load(1, 4); // 1 is now the most recent
        load(3, 4); // 2 leaves
        assert!(c.contains(&1) && c.contains(&3) && !c.contains(&2));
        assert_eq!((c.held(), c.loads()), (8, 3));
        // Heavier than the bound alone: returned, and the only entry kept.
        assert_eq!(*c.get_or_load(&9, || Ok::<_, ()>((9, 50))).unwrap(), 9);
        assert_eq!(c.held(), 50);
        // A failed load leaves the cache as it was.
        assert!(c.get_or_load(&7, || Err("unreadable")).is_err());
        assert_eq!((c.held(), c.loads()), (50, 4));
    }
}
