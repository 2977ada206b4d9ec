//! The bridge's DroneCAN node on a bus with another implementation: the `dronecan` package
//! (PyPI) as a node of its own on ArduPilot SITL's multicast CAN, in a network namespace of
//! the test's own. It commands the servos with ArrayCommand, asks the bridge's node who it is,
//! and hears its NodeStatus and each servo's actuator Status, all through `dronecan`'s own
//! transport and decoder.

mod common;

use common::mapping::Mapping;
use common::{Chain, netns};
use lj9da_sim::BusEvent;
use lj9da_sim::protocol::host_packet::HostPacket;
use serde_json::Value;
use std::time::Duration;

/// Node 100 on `mcast:0`: ArrayCommand (PWM 1800 µs for actuators 1–4, then 1300 µs) at 50 Hz
/// for 3 s, GetNodeInfo to node 42; prints what it heard from node 42 as JSON.
const PEER: &str = r#"
import json, time
import dronecan
node = dronecan.make_node("mcast:0", node_id=100)
heard = {"status": [], "node_status": [], "info": None}
def on_status(e):
    if e.transfer.source_node_id == 42:
        heard["status"].append([e.message.actuator_id, e.message.position])
def on_node_status(e):
    if e.transfer.source_node_id == 42:
        m = e.message
        heard["node_status"].append([m.health, m.mode, m.vendor_specific_status_code])
def on_info(e):
    if e is not None:
        r = e.response
        heard["info"] = {"name": bytes(r.name).decode(),
                         "unique_id": list(r.hardware_version.unique_id),
                         "software": [r.software_version.major, r.software_version.minor]}
node.add_handler(dronecan.uavcan.equipment.actuator.Status, on_status)
node.add_handler(dronecan.uavcan.protocol.NodeStatus, on_node_status)
actuator = dronecan.uavcan.equipment.actuator
t0 = time.time()
asked = False
while time.time() - t0 < 3.0:
    us = 1800 if time.time() - t0 < 1.5 else 1300
    node.broadcast(actuator.ArrayCommand(commands=[
        actuator.Command(actuator_id=i, command_type=4, command_value=us) for i in (1, 2, 3, 4)]))
    if not asked and time.time() - t0 > 0.5:
        node.request(dronecan.uavcan.protocol.GetNodeInfo.Request(), 42, on_info)
        asked = True
    node.spin(0.02)
print(json.dumps(heard))
"#;

/// `test` in a network namespace of its own, given the Python with `dronecan` (installed
/// first: the namespace has no way out to PyPI); one line and no test where the namespace
/// cannot be made (a failure under `CI=true`).
fn on_the_bus<F: std::future::Future<Output = ()>>(test: impl FnOnce(std::path::PathBuf) -> F) {
    let python = common::python::dronecan_python();
    if !netns::enter_or_say() {
        return;
    }
    tokio::runtime::Builder::new_multi_thread()
        .worker_threads(2)
        .enable_all()
        .build()
        .unwrap()
        .block_on(test(python));
}

/// Run `script` with `python`; what it printed, as JSON.
async fn run_peer(python: std::path::PathBuf, script: &'static str) -> Value {
    let out = tokio::task::spawn_blocking(move || {
        std::process::Command::new(python)
            .arg("-c")
            .arg(script)
            .output()
            .expect("the dronecan peer runs")
    })
    .await
    .unwrap();
    assert!(
        out.status.success(),
        "the dronecan peer: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice(&out.stdout).expect("the peer's JSON")
}

#[test]
fn a_dronecan_node_commands_the_servos_and_reads_the_bridges_node() {
    on_the_bus(|python| async move {
        let mapping = Mapping::four_servos()
            .with("[mavlink]", "failsafe_timeout_ms = 500")
            .with("[bridge]", "commands = \"dronecan\"")
            .with(
                "[dronecan]",
                "interface = \"mcast:0\"\nnode_id = 42\nstatus_hz = 10",
            );
        let chain = Chain::start(mapping, false).await;
        chain
            .wait_view("the servos online", Duration::from_secs(10), |v| {
                !v.servos.is_empty() && v.servos.iter().all(|s| s.report.online())
            })
            .await;
        let events = chain.sims[0].handle().subscribe();
        let heard = run_peer(python, PEER).await;

        // Its commands moved every servo: 1800 µs is +11.67 mm, 1300 µs −9.17 mm.
        let goals: Vec<Vec<(u8, i16)>> = events
            .try_iter()
            .filter_map(|e| match e {
                BusEvent::Packet(p) if matches!(p.packet, HostPacket::Long(_)) => {
                    Some(p.packet.goal_positions())
                }
                _ => None,
            })
            .collect();
        for want in [1167, -917] {
            assert!(
                goals
                    .iter()
                    .any(|g| g.len() == 4 && g.iter().all(|(_, p)| *p == want)),
                "no long packet with every servo at {want}: {goals:?}"
            );
        }

        // Who the node is, as dronecan decodes it.
        let info = &heard["info"];
        assert_eq!(info["name"], "org.lj9da.bridge", "{heard}");
        assert_eq!(info["unique_id"].as_array().map(Vec::len), Some(16));
        // NodeStatus once a second, healthy and operational, no servo unwell.
        let node_status = heard["node_status"].as_array().unwrap();
        assert!((2..=4).contains(&node_status.len()), "{node_status:?}");
        assert!(
            node_status
                .iter()
                .all(|s| s == &serde_json::json!([0, 0, 0])),
            "{node_status:?}"
        );
        // Each servo's Status under its actuator id, at about 10 Hz, at the position read.
        let status = heard["status"].as_array().unwrap();
        for id in 1..=4u64 {
            let mine: Vec<f64> = status
                .iter()
                .filter(|s| s[0].as_u64() == Some(id))
                .filter_map(|s| s[1].as_f64())
                .collect();
            assert!(
                mine.len() >= 20,
                "actuator {id}: {} Status in 3 s",
                mine.len()
            );
            assert!(
                mine.iter().any(|m| (m - 0.01167).abs() < 0.0002),
                "actuator {id} never said +11.67 mm: {mine:?}"
            );
        }
        chain.stop().await;
    });
}

/// Node 100 on `mcast:0` as the bus's allocator (`dronecan`'s CentralizedServer with its node
/// monitor) for 8 s; then asks GetNodeInfo of every node it gave an id to, and prints its
/// allocation table, the NodeStatus sources it heard and the answers, as JSON.
const ALLOCATOR: &str = r#"
import json, time
import dronecan
from dronecan.app.node_monitor import NodeMonitor
from dronecan.app.dynamic_node_id import CentralizedServer
node = dronecan.make_node("mcast:0", node_id=100)
monitor = NodeMonitor(node)
server = CentralizedServer(node, monitor)
sources = set()
node.add_handler(dronecan.uavcan.protocol.NodeStatus, lambda e: sources.add(e.transfer.source_node_id))
node.spin(8.0)
table = [[bytes(u).hex() if u else None, n] for u, n in server.get_allocation_table()]
infos = {}
def asker(n):
    def on_info(e):
        if e is not None:
            infos[n] = {"name": bytes(e.response.name).decode(),
                        "unique_id": bytes(e.response.hardware_version.unique_id).hex()}
    return on_info
for u, n in table:
    if n != 100:
        node.request(dronecan.uavcan.protocol.GetNodeInfo.Request(), n, asker(n))
node.spin(1.5)
print(json.dumps({"table": table, "sources": sorted(sources), "infos": infos}))
"#;

#[test]
fn a_dronecan_allocator_gives_the_bridge_its_node_id() {
    on_the_bus(|python| async move {
        // The allocator first: it grants nothing until it has heard the bus for a while.
        let peer = tokio::spawn(run_peer(python, ALLOCATOR));
        let mapping = Mapping::four_servos().with(
            "[dronecan]",
            "interface = \"mcast:0\"\nnode_id = \"dynamic\"",
        );
        let chain = Chain::start(mapping, false).await;
        let heard = peer.await.unwrap();
        // One id given (besides the allocator's own), to the bridge's unique id: the one
        // its GetNodeInfo gives, from a node that then speaks under that id.
        let given: Vec<&Value> = heard["table"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|e| e[1] != 100)
            .collect();
        assert_eq!(given.len(), 1, "{heard}");
        let (uid, id) = (given[0][0].as_str().unwrap(), given[0][1].as_u64().unwrap());
        assert!((1..=125).contains(&id), "{heard}");
        let info = &heard["infos"][id.to_string()];
        assert_eq!(info["name"], "org.lj9da.bridge", "{heard}");
        assert_eq!(info["unique_id"], uid, "{heard}");
        assert!(
            heard["sources"]
                .as_array()
                .unwrap()
                .iter()
                .any(|s| s.as_u64() == Some(id)),
            "no NodeStatus from node {id}: {heard}"
        );
        chain.stop().await;
    });
}
