//! Wear: friction current in proportion to the rod's speed, and the heat it brings; a stiff spot
//! over part of the stroke that loads the rod there, moving or holding.

mod common;

use std::time::Duration;

use common::{VirtualBus, force, goal};
use lj9da_sim::{StiffSpot, Wear};

/// Servos 1 and 2 sweep ±10 mm together for `seconds`; returns each one's mean current over
/// the samples taken while it moved, and its temperature at the end.
fn sweep(bus: &mut VirtualBus, seconds: u32) -> [(f64, f64); 2] {
    let mut sums = [(0.0, 0u32); 2];
    let mut target = 1000i16;
    for step in 0..seconds * 50 {
        if step % 25 == 0 {
            target = -target;
            bus.transact(&goal(1, target));
            bus.transact(&goal(2, target));
        }
        bus.wait(Duration::from_millis(20));
        for (slot, sum) in sums.iter_mut().enumerate() {
            let id = slot as u8 + 1;
            let snapshot = bus.model.snapshot(bus.now, id).unwrap();
            if (snapshot.goal_mm - snapshot.rod_mm).abs() > 0.5 {
                sum.0 += f64::from(snapshot.current_a);
                sum.1 += 1;
            }
        }
    }
    let mut out = [(0.0, 0.0); 2];
    for (slot, (sum, n)) in sums.iter().enumerate() {
        let snapshot = bus.model.snapshot(bus.now, slot as u8 + 1).unwrap();
        out[slot] = (sum / f64::from(*n), f64::from(snapshot.temperature_c));
    }
    out
}

#[test]
fn friction_draws_current_in_proportion_to_speed_and_heats_the_servo() {
    let mut bus = VirtualBus::with_ids(&[1, 2]);
    bus.transact(&force(1, 1));
    bus.transact(&force(2, 1));
    assert!(bus.model.set_wear(
        bus.now,
        2,
        Wear {
            friction_a_per_mm_s: 0.004,
            stiff_spot: None,
            ..Wear::default()
        },
    ));
    let [(new, new_c), (worn, worn_c)] = sweep(&mut bus, 60);
    // 20 mm in 0.5 s at up to 105 mm/s: the worn servo draws ≈ 0.004 A·s/mm × its speed more.
    assert!(new > 0.2 && new < 0.35, "new servo: {new} A");
    assert!(worn > new + 0.15, "worn {worn} A vs new {new} A");
    assert!(worn_c > new_c + 1.0, "worn {worn_c} °C vs new {new_c} °C");
    // Friction needs motion: holding still, both draw the holding current.
    bus.wait(Duration::from_secs(2));
    let held: Vec<f32> = bus
        .model
        .snapshots(bus.now)
        .iter()
        .map(|s| s.current_a)
        .collect();
    assert!((held[0] - held[1]).abs() < 1e-6, "{held:?}");
}

#[test]
fn a_stiff_spot_loads_the_rod_over_its_part_of_the_stroke_only() {
    let mut bus = VirtualBus::with_ids(&[1]);
    bus.transact(&force(1, 1));
    let spot = Wear {
        friction_a_per_mm_s: 0.0,
        stiff_spot: Some(StiffSpot {
            from_mm: 4.0,
            to_mm: 8.0,
            load_n: 100.0,
        }),
        ..Wear::default()
    };
    bus.model.set_wear(bus.now, 1, spot);
    let holding_at = |bus: &mut VirtualBus, centi: i16| {
        bus.transact(&goal(1, centi));
        bus.wait(Duration::from_secs(1));
        bus.model.snapshot(bus.now, 1).unwrap().current_a
    };
    let outside = holding_at(&mut bus, 200);
    let inside = holding_at(&mut bus, 600);
    let beyond = holding_at(&mut bus, 1000);
    assert!((outside - 0.07).abs() < 1e-3, "{outside} A outside");
    assert!(inside > 0.9, "{inside} A holding in the stiff spot");
    assert!((beyond - 0.07).abs() < 1e-3, "{beyond} A beyond");
    bus.model.set_wear(bus.now, 1, Wear::default());
    assert!((holding_at(&mut bus, 600) - 0.07).abs() < 1e-3);
}
