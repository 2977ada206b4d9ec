//! The servos commanded by DroneCAN's ArrayCommand, through the sans-IO core: one source
//! commands them (`[bridge] commands`), each servo follows its `dronecan_id` by the mapping's
//! law, and the failsafe is kept as on the MAVLink path.

mod mavlink_support;

use lj9da_bridge::bus::Goal;
use lj9da_bridge::config::Config;
use lj9da_bridge::dronecan::messages::{Command, CommandType};
use lj9da_bridge::mavlink::BridgeCore;
use lj9da_bridge::mavlink::core::sys_status;
use lj9da_bridge::protocol::MmCenti;
use mavlink::dialects::common::*;
use mavlink_support::*;
use std::time::{Duration, Instant};

/// The three servos of the MAVLink tests (channels 1, 18, 9; the second reversed with a 5 mm
/// failsafe, the third force off), on DroneCAN's commands; the gear answers actuator id 30.
fn mapping(commands: &str) -> String {
    let with_id = MAPPING.replacen("actuator = 2\n", "actuator = 2\ndronecan_id = 30\n", 1);
    format!(
        "{with_id}\n[bridge]\ncommands = \"{commands}\"\n\n[dronecan]\ninterface = \"mcast:0\"\nnode_id = 42\n"
    )
}

fn core_on(commands: &str, t0: Instant) -> BridgeCore {
    let cfg = Config::parse(&mapping(commands), "test.toml").expect("valid");
    let mut c = BridgeCore::new(cfg, t0);
    c.handle_message(0, &header(AP), &autopilot_heartbeat(), t0);
    c.handle_message(0, &header(AP), &sys_status(false), t0);
    messages(&mut c);
    c
}

fn pwm(actuator_id: u8, us: f32) -> Command {
    Command {
        actuator_id,
        command_type: CommandType::Pwm,
        value: us,
    }
}

fn unitless(actuator_id: u8, value: f32) -> Command {
    Command {
        actuator_id,
        command_type: CommandType::Unitless,
        value,
    }
}

fn ms(n: u64) -> Duration {
    Duration::from_millis(n)
}

#[test]
fn each_servo_follows_its_actuator_id_as_the_same_pulse_over_mavlink_moves_it() {
    let t0 = Instant::now();
    let mut can = core_on("dronecan", t0);
    let mut mav = running(t0);
    for (k, us) in [1000u16, 1234, 1520, 1777, 2000].into_iter().enumerate() {
        let t = t0 + ms(20 * (k as u64 + 1));
        can.handle_can_commands(
            &[
                pwm(1, f32::from(us)),
                pwm(18, f32::from(us)),
                pwm(30, f32::from(us)),
            ],
            t,
        );
        mav.handle_message(0, &header(AP), &outputs(0, &[(1, us), (9, us)]), t);
        mav.handle_message(0, &header(AP), &outputs(1, &[(2, us)]), t);
        let mut got = commands(&mut can);
        let mut want = commands(&mut mav);
        got.sort_by_key(|(i, _)| *i);
        want.sort_by_key(|(i, _)| *i);
        assert_eq!(got, want, "{us} µs");
        assert_eq!(got.len(), 3, "{us} µs: {got:?}");
    }
}

#[test]
fn ardupilots_unitless_value_is_taken_back_to_its_pulse() {
    let t0 = Instant::now();
    let mut c = core_on("dronecan", t0);
    // ArduPilot sends (p − 1000)/500 − 1: 1760 µs is 0.52, and maps as 1760 µs does.
    c.handle_can_commands(&[unitless(1, 0.52)], t0 + ms(10));
    assert_eq!(
        commands(&mut c),
        [(0, Goal::Position(MmCenti(1000)))],
        "1760 µs is +10.00 mm in the servo's own PWM law"
    );
}

#[test]
fn with_dronecan_commanding_mavlink_moves_nothing_and_asks_for_no_stream() {
    let t0 = Instant::now();
    let mut c = core_on("dronecan", t0);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1800)]), t0 + ms(10));
    assert_eq!(commands(&mut c), []);
    let set_servo = command_long(
        MavCmd::MAV_CMD_DO_SET_SERVO,
        [1.0, 1800.0, 0.0, 0.0, 0.0, 0.0, 0.0],
        (7, 140),
    );
    c.handle_message(0, &header(AP), &set_servo, t0 + ms(20));
    assert_eq!(commands(&mut c), []);
    let out = messages(&mut c);
    assert_eq!(
        acks(&out),
        [(
            MavCmd::MAV_CMD_DO_SET_SERVO,
            MavResult::MAV_RESULT_DENIED,
            7,
            1
        )]
    );
    for t in (1..40).map(|k| t0 + ms(100 * k)) {
        c.handle_timeout(t, &[]);
    }
    let asked = messages(&mut c).into_iter().any(|o| {
        matches!(&o.message, MavMessage::COMMAND_LONG(m)
            if m.command == MavCmd::MAV_CMD_SET_MESSAGE_INTERVAL)
    });
    assert!(!asked, "the output stream was asked for");
}

#[test]
fn with_mavlink_commanding_an_array_command_moves_nothing() {
    let t0 = Instant::now();
    let mut c = core_on("mavlink", t0);
    c.handle_can_commands(&[pwm(1, 1800.0)], t0 + ms(10));
    assert_eq!(commands(&mut c), []);
    c.handle_message(0, &header(AP), &outputs(0, &[(1, 1800)]), t0 + ms(20));
    assert!(
        commands(&mut c).contains(&(0, Goal::Position(MmCenti(1167)))),
        "the MAVLink output moves it"
    );
}

#[test]
fn commands_that_stop_bring_each_servos_failsafe_and_the_next_ends_it() {
    let t0 = Instant::now();
    let mut c = core_on("dronecan", t0);
    let all = [pwm(1, 1600.0), pwm(18, 1600.0), pwm(30, 1600.0)];
    c.handle_can_commands(&all, t0);
    commands(&mut c);
    messages(&mut c);
    c.handle_timeout(t0 + ms(499), &[]);
    assert_eq!(commands(&mut c), [], "before the timeout");
    let deadline = c.poll_timeout().expect("a failsafe deadline");
    assert_eq!(deadline, t0 + ms(500));
    c.handle_timeout(t0 + ms(500), &[]);
    let mut got = commands(&mut c);
    got.sort_by_key(|(i, _)| *i);
    assert_eq!(
        got,
        [
            (0, Goal::Hold),
            (1, Goal::Position(MmCenti(500))),
            (2, Goal::Off)
        ]
    );
    let texts = statustexts(&messages(&mut c));
    assert!(
        texts
            .iter()
            .any(|(_, t)| t.contains("failsafe: no outputs for 500 ms")),
        "{texts:?}"
    );
    assert!(c.in_failsafe());
    c.handle_can_commands(&all, t0 + ms(700));
    assert!(!c.in_failsafe());
    assert_eq!(commands(&mut c).len(), 3);
}

#[test]
fn a_servo_whose_actuator_id_stops_coming_takes_its_failsafe_alone() {
    let t0 = Instant::now();
    let mut c = core_on("dronecan", t0);
    c.handle_can_commands(&[pwm(1, 1600.0), pwm(30, 1600.0)], t0);
    commands(&mut c);
    let mut t = t0;
    while t < t0 + ms(600) {
        t += ms(20);
        // The gear's id 30 is left out from now on.
        c.handle_can_commands(&[pwm(1, 1600.0), pwm(18, 1600.0)], t);
        c.handle_timeout(t, &[]);
    }
    let got = commands(&mut c);
    assert!(got.contains(&(2, Goal::Off)), "{got:?}");
    assert!(c.servo_in_failsafe(2));
    assert!(!c.servo_in_failsafe(0));
    let texts = statustexts(&messages(&mut c));
    assert!(
        texts
            .iter()
            .any(|(_, t)| t.contains("gear: failsafe, no ch30")),
        "{texts:?}"
    );
}

#[test]
fn a_parameter_changed_moves_the_servo_to_its_last_command_under_the_new_mapping() {
    let t0 = Instant::now();
    let text = mapping("dronecan");
    let mut c = core_on("dronecan", t0);
    let mut file = lj9da_bridge::config::edit::MappingFile::in_memory(&text, "test.toml").unwrap();
    c.handle_can_commands(
        &[pwm(1, 1800.0), pwm(18, 1800.0), pwm(30, 1800.0)],
        t0 + ms(20),
    );
    let before: Vec<(usize, Goal)> = commands(&mut c)
        .into_iter()
        .filter(|(i, _)| *i == 0)
        .collect();
    assert_eq!(before.len(), 1, "{before:?}");
    let Goal::Position(p) = before[0].1 else {
        panic!("{before:?}")
    };
    c.handle_message(
        0,
        &header((255, 190)),
        &MavMessage::PARAM_SET(PARAM_SET_DATA {
            param_value: 1.0,
            target_system: 7,
            target_component: 140,
            param_id: "S1_REV".into(),
            param_type: MavParamType::MAV_PARAM_TYPE_REAL32,
        }),
        t0 + ms(30),
    );
    let set = c.poll_param_set().expect("S1_REV is a parameter");
    let result = file.apply(&set.edits).map_err(|e| e.reason());
    c.handle_message(0, &header((255, 190)), &sys_status(false), t0 + ms(31));
    c.param_set_done(&set, result, t0 + ms(31));
    // Reversed, the same 1800 µs is the mirror of the goal before, at once: no new
    // ArrayCommand needed.
    let after: Vec<(usize, Goal)> = commands(&mut c)
        .into_iter()
        .filter(|(i, _)| *i == 0)
        .collect();
    assert_eq!(
        after,
        vec![(0, Goal::Position(MmCenti(-p.0)))],
        "before {p:?}"
    );
}
