use super::*;

#[test]
fn a_write_moves_the_sleeping_thread_s_timer_to_the_bus_master_s_next_deadline() {
    let t = Instant::now();
    let ms = |n: u64| t + Duration::from_millis(n);
    // Asleep until its own 18 ms, no timer: a deadline before then sets the timer; one
    // after it, or none, changes nothing.
    assert_eq!(rearm(ms(18), ms(18), Some(ms(2))), Rearm::Set(ms(2)));
    assert_eq!(rearm(ms(18), ms(18), Some(ms(30))), Rearm::Keep);
    assert_eq!(rearm(ms(18), ms(18), None), Rearm::Keep);
    // A tick's first message brought the wake-up forward to the end of its gathering
    // window (0.1 ms); the message that closed the window wrote the frame, and the next
    // deadline is the look at the reply behind it (4 ms): the timer goes back to it.
    assert_eq!(rearm(ms(0), ms(18), Some(ms(4))), Rearm::Set(ms(4)));
    // Nothing due before the thread's own wait ends: the timer is unset.
    assert_eq!(rearm(ms(4), ms(18), Some(ms(25))), Rearm::Unset);
    assert_eq!(rearm(ms(4), ms(18), None), Rearm::Unset);
    // Sooner still, or the same.
    assert_eq!(rearm(ms(4), ms(18), Some(ms(3))), Rearm::Set(ms(3)));
    assert_eq!(rearm(ms(4), ms(18), Some(ms(4))), Rearm::Keep);
}

#[test]
fn a_late_wake_up_is_told_once_then_only_counted() {
    let ms = Duration::from_millis;
    let mut late = LateWakeups::default();
    let first = late.note(ms(2)).expect("the first is told");
    assert!(first.contains("2.0 ms late"), "{first}");
    for _ in 0..1000 {
        assert_eq!(late.note(ms(3)), None);
    }
}
