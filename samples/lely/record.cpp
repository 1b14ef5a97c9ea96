// record.cpp - record real CANopen NMT traffic from the Lely CANopen stack.
//
// One process runs a Lely CiA 302 NMT master (lely::canopen::BasicMaster,
// node-ID 1, configured from master.dcf made by Lely's dcfgen from master.yml)
// and three Lely slaves (lely::canopen::BasicSlave, node-IDs 2, 3, 4, each
// from slave.eds) on Lely's userspace virtual CAN bus
// (lely::io::VirtualCanController), all driven by one event loop
// (lely::ev::Loop on a lely::io::Poll) with CLOCK_MONOTONIC timers.
//
// Every device sits on its own small virtual CAN bus ("stub") with its own
// VirtualCanController; a "connector" (two VirtualCanChannels, one on the
// stub and one on the main bus) copies frames between the stub and the main
// bus. Unplugging a device stops the copying in both directions: the device
// keeps running (timers, state, heartbeats) but nothing it sends reaches the
// bus and nothing from the bus reaches it, as with a pulled CAN connector.
// (Closing a Lely VirtualCanChannel under a running node would make its CAN
// network busy-loop on read errors, so we do not do that.)
//
// One more VirtualCanChannel on the main bus only receives, and writes every
// frame it gets as a candump -L line. A VirtualCanController delivers a frame
// to every channel on the bus except the sender, so the recorder sees every
// frame exactly once. The program checks this at the end: frames put on the
// main bus by the connectors == frames logged, and every connector received
// all logged frames except its own.
//
// Timestamps are the ones the main bus controller gives each frame (Lely
// stamps a frame with its controller's clock, CLOCK_MONOTONIC here, when it
// is put on the bus), shifted so that the program start is at 1700000000 s.
//
// Usage: record SCENARIO OUT.log   (run in the directory holding master.dcf,
//        master.bin, slave2.bin ... slave4.bin and slave.eds; the scenarios
//        keepalive and mandatory_lost load their master's files from the
//        subfolders keepalive/ and mandatory/ instead, see kScenarios)
// Events seen by the master and the slaves (boot, heartbeat/guarding events,
// NMT commands) are printed on stderr as "# t=SECONDS ..." lines, t relative
// to the program start.
//
// Part of nmtcheck (MIT, see pyproject.toml). It contains no Lely code; it
// only includes the headers of, and links against, an installed lely-core
// (Apache-2.0).

#include "recorder.hpp"

namespace {

class Master : public canopen::BasicMaster {
 public:
  using BasicMaster::BasicMaster;

 private:
  void
  OnCommand(NmtCommand cs) noexcept override {
    event("master: own NMT state change by command %s", cs_name(cs));
    BasicMaster::OnCommand(cs);
  }
  void
  OnHeartbeat(uint8_t id, bool occurred) noexcept override {
    event("master: heartbeat event for node %d %s", id,
          occurred ? "occurred (timeout)" : "resolved");
    BasicMaster::OnHeartbeat(id, occurred);
  }
  void
  OnState(uint8_t id, NmtState st) noexcept override {
    event("master: node %d state %s", id, st_name(st));
    BasicMaster::OnState(id, st);
  }
  void
  OnNodeGuarding(uint8_t id, bool occurred) noexcept override {
    event("master: node guarding event for node %d %s", id,
          occurred ? "occurred (timeout)" : "resolved");
    BasicMaster::OnNodeGuarding(id, occurred);
  }
  void
  OnBoot(uint8_t id, NmtState st, char es,
         const std::string& what) noexcept override {
    event("master: boot-slave process for node %d finished: state %s, "
          "error status '%c' %s",
          id, st_name(st), es ? es : '0', what.c_str());
    BasicMaster::OnBoot(id, st, es, what);
  }
  void
  OnEmcy(uint8_t id, uint16_t eec, uint8_t er, uint8_t msef[5]) noexcept
      override {
    event("master: EMCY from node %d: %04X %02X", id, eec, er);
    BasicMaster::OnEmcy(id, eec, er, msef);
  }
};

struct Scenario {
  const char* name;
  const char* what;
};

const Scenario kScenarios[] = {
    {"healthy", "master + 3 slaves power on together, run 10 s"},
    {"late_master", "slaves power on at 0 s, the master at 3 s, run to 12 s"},
    {"unplugged_heartbeat",
     "node 3 (heartbeat) unplugged at 5 s, plugged back at 7 s, run to 12 s"},
    {"unplugged_guarded",
     "node 4 (node guarding) unplugged at 5 s, plugged back at 7 s, run to "
     "12 s"},
    {"reboot",
     "node 3 powers off at 5 s and on again at 5.15 s (boot-up without an NMT "
     "command), run to 11 s"},
    {"stop_start_sdo",
     "master stops node 3 at 4 s, reads 1018h:01 from it at 4.5 s (500 ms "
     "SDO timeout), starts it at 6 s, reads 1018h:01 again at 7 s, run to 10 "
     "s"},
    {"broadcast",
     "master sends NMT enter pre-operational to all at 4 s and start all at "
     "6 s, run to 10 s"},
    {"self_1017",
     "node 2's application writes its own 1017h = 250 ms at 4 s (right "
     "after one of its heartbeats), run to 10 s"},
    {"keepalive",
     "as healthy, but with keepalive/master.dcf: node 2 has the keep-alive "
     "bit (1F81h bit 4) and produces heartbeats from power-on "
     "(keepalive/slave_hb.eds), so the master resets node by node; run 10 s"},
    {"reset_all",
     "master sends NMT reset node, all nodes, at 4.37 s, in the same instant "
     "as the slaves' application queues a TPDO; run to 10 s"},
    {"mandatory_lost",
     "with mandatory/master.dcf: node 3 is a mandatory slave and 1F80h bit 4 "
     "is set; node 3 is unplugged at 5 s (the master resets all nodes, "
     "itself included) and plugged back at 7 s; run to 12 s"},
    {"mandatory_reboot",
     "as mandatory_lost, but node 3 powers on again (boot-up) at 7 s instead "
     "of being plugged back; run to 12 s"},
};

void
usage(const char* argv0) {
  std::fprintf(stderr, "usage: %s SCENARIO OUT.log\nscenarios:\n", argv0);
  for (const auto& s : kScenarios)
    std::fprintf(stderr, "  %-20s %s\n", s.name, s.what);
}

}  // namespace

int
main(int argc, char* argv[]) {
  if (argc != 3) {
    usage(argv[0]);
    return 2;
  }
  const std::string scenario = argv[1];
  bool known = false;
  for (const auto& s : kScenarios) known = known || scenario == s.name;
  if (!known) {
    usage(argv[0]);
    return 2;
  }
  // Where the master's DCF and concise DCFs are (dcfgen output) and which EDS
  // each slave powers on with.
  std::string dir;
  std::map<int, std::string> slave_eds;
  for (int id : {2, 3, 4}) slave_eds[id] = "slave.eds";
  if (scenario == "keepalive") {
    dir = "keepalive/";
    slave_eds[2] = "keepalive/slave_hb.eds";
  } else if (scenario == "mandatory_lost" || scenario == "mandatory_reboot") {
    dir = "mandatory/";
  }

  FILE* out = std::fopen(argv[2], "w");
  if (!out) {
    std::perror(argv[2]);
    return 2;
  }

  io::IoGuard io_guard;
  io::Context ctx;
  io::Poll poll(ctx);
  ev::Loop loop(poll.get_poll());
  ev_exec_t* exec = loop.get_executor();

  g_start = mono_now();

  // The main bus, with every frame time-stamped by CLOCK_MONOTONIC.
  io::VirtualCanController bus(io::clock_monotonic);
  Recorder recorder(ctx, exec, bus, out, "vcan0");

  std::map<int, std::unique_ptr<Connector>> conn;
  for (int id : {1, 2, 3, 4})
    conn[id] = std::make_unique<Connector>(ctx, exec, bus, id);

  std::map<int, std::unique_ptr<io::Timer>> dev_timer;
  std::map<int, std::unique_ptr<Slave>> slaves;
  std::unique_ptr<Master> master;

  // Scheduled actions: one io::Timer each, relative to the program start.
  std::vector<std::unique_ptr<io::Timer>> timers;
  auto at = [&](double t, std::function<void()> f) {
    auto tm = std::make_unique<io::Timer>(poll, exec, CLOCK_MONOTONIC);
    auto when = g_start + std::chrono::duration_cast<std::chrono::nanoseconds>(
                              std::chrono::duration<double>(t));
    tm->settime(io::Timer::time_point(when));
    tm->submit_wait(exec, [f](int, std::error_code ec) {
      if (!ec) f();
    });
    timers.push_back(std::move(tm));
  };

  auto power_on_slave = [&](int id) {
    event("node %d: power on", id);
    dev_timer[id] = std::make_unique<io::Timer>(poll, exec, CLOCK_MONOTONIC);
    slaves[id] = std::make_unique<Slave>(exec, *dev_timer[id], conn[id]->dev,
                                         slave_eds[id], id);
    slaves[id]->Reset();
  };
  auto power_on_master = [&]() {
    event("master: power on");
    dev_timer[1] = std::make_unique<io::Timer>(poll, exec, CLOCK_MONOTONIC);
    master = std::make_unique<Master>(exec, *dev_timer[1], conn[1]->dev,
                                      dir + "master.dcf", dir + "master.bin",
                                      1);
    master->Reset();
  };
  auto unplug = [&](int id) {
    event("node %d: unplugged", id);
    conn[id]->set_plugged(false);
  };
  auto plug = [&](int id) {
    event("node %d: plugged in", id);
    conn[id]->set_plugged(true);
  };

  // The slaves' application: every 500 ms bump the counter (TPDO1).
  io::Timer app_timer(poll, exec, CLOCK_MONOTONIC);
  std::function<void(int, std::error_code)> app_tick;
  // Called at the start of the next application tick, before the slaves
  // queue their TPDOs (scenario reset_all).
  std::function<void()> before_tick;
  app_tick = [&](int, std::error_code ec) {
    if (ec) return;
    if (before_tick) {
      auto f = std::move(before_tick);
      before_tick = nullptr;
      f();
    }
    for (auto& kv : slaves) kv.second->Tick();
    app_timer.submit_wait(exec, app_tick);
  };
  // (Off the whole-second grid the scenario actions use, so a TPDO is never
  // queued in the same instant as an NMT command.)
  app_timer.settime(io::Timer::time_point(g_start + 370ms), 500ms);
  app_timer.submit_wait(exec, app_tick);

  double end = 10.0;
  bool armed_1017 = false;
  if (scenario == "late_master") {
    at(0.0, [&] {
      for (int id : {2, 3, 4}) power_on_slave(id);
    });
    at(3.0, [&] { power_on_master(); });
    end = 12.0;
  } else {
    at(0.0, [&] {
      power_on_master();
      for (int id : {2, 3, 4}) power_on_slave(id);
    });
  }
  if (scenario == "unplugged_heartbeat" || scenario == "unplugged_guarded") {
    int id = scenario == "unplugged_heartbeat" ? 3 : 4;
    at(5.0, [&, id] { unplug(id); });
    at(7.0, [&, id] { plug(id); });
    end = 12.0;
  } else if (scenario == "reboot") {
    at(5.0, [&] {
      event("node 3: power off");
      unplug(3);
    });
    at(5.15, [&] {
      plug(3);
      event("node 3: power on again (reboot, application reset)");
      slaves[3]->Reset();
    });
    end = 11.0;
  } else if (scenario == "stop_start_sdo") {
    auto read_identity = [&]() {
      event("master: SDO upload request 1018h:01 from node 3");
      master->SubmitRead<uint32_t>(
          exec, 3, 0x1018, 1,
          [](uint8_t id, uint16_t idx, uint8_t subidx, std::error_code ec,
             uint32_t value) {
            if (ec)
              event("master: SDO upload %04Xh:%02X from node %d failed: %s",
                    idx, subidx, id, ec.message().c_str());
            else
              event("master: SDO upload %04Xh:%02X from node %d = 0x%08X", idx,
                    subidx, id, value);
          },
          500ms);
    };
    at(4.0, [&] {
      event("master: NMT stop node 3");
      master->Command(NmtCommand::STOP, 3);
    });
    at(4.5, read_identity);
    at(6.0, [&] {
      event("master: NMT start node 3");
      master->Command(NmtCommand::START, 3);
    });
    at(7.0, read_identity);
  } else if (scenario == "broadcast") {
    at(4.0, [&] {
      event("master: NMT enter pre-operational, all nodes");
      master->Command(NmtCommand::ENTER_PREOP, 0);
    });
    at(6.0, [&] {
      event("master: NMT start, all nodes");
      master->Command(NmtCommand::START, 0);
    });
  } else if (scenario == "reset_all") {
    // At the application tick of 4.37 s: first the master's application sends
    // NMT reset node to all nodes, then (same callback) the slaves'
    // application triggers TPDO1. The TPDOs reach the bus after the command
    // but before the slaves have processed it.
    at(4.2, [&] {
      before_tick = [&] {
        event("master: NMT reset node, all nodes");
        master->Command(NmtCommand::RESET_NODE, 0);
      };
    });
  } else if (scenario == "mandatory_lost") {
    at(5.0, [&] { unplug(3); });
    at(7.0, [&] { plug(3); });
    end = 12.0;
  } else if (scenario == "mandatory_reboot") {
    at(5.0, [&] {
      event("node 3: power off");
      unplug(3);
    });
    at(7.0, [&] {
      plug(3);
      event("node 3: power on again (application reset)");
      slaves[3]->Reset();
    });
    end = 12.0;
  } else if (scenario == "self_1017") {
    // At 4 s, right after node 2's next heartbeat is on the bus, its
    // application writes 1017h = 250 ms (so the gap after the change is the
    // new 250 ms, not up to 100 + 250 ms).
    at(4.0, [&] { armed_1017 = true; });
    conn[2]->on_sent = [&](const can_msg& msg) {
      if (!armed_1017 || msg.id != 0x702) return;
      armed_1017 = false;
      ev::Executor(exec).post([&] {
        event("node 2: application writes its own 1017h = 250 ms");
        slaves[2]->SetHeartbeat(250);
      });
    };
  }

  // End: disconnect every device from the main bus, let in-flight frames
  // drain, then stop the loop.
  at(end, [&] {
    for (auto& kv : conn) kv.second->set_plugged(false);
  });
  at(end + 0.2, [&] { loop.stop(); });

  loop.run();
  std::fflush(out);

  // Every frame exactly once: what the connectors put on the main bus must be
  // what the recorder logged, and each connector must have received all of
  // it but its own frames.
  uint64_t sent = 0;
  int rc = 0;
  for (auto& kv : conn) {
    const Connector& c = *kv.second;
    sent += c.sent;
    std::fprintf(stderr,
                 "# node %d: sent %" PRIu64 " (dropped while unplugged %" PRIu64
                 "), received %" PRIu64 " (delivered %" PRIu64 "), errors %" PRIu64
                 "\n",
                 kv.first, c.sent, c.sent_lost, c.received, c.delivered,
                 c.errors);
    if (c.errors) rc = 1;
  }
  for (auto& kv : conn) {
    const Connector& c = *kv.second;
    if (c.received + c.sent != recorder.frames()) {
      std::fprintf(stderr, "# MISMATCH: node %d received+sent != logged\n",
                   kv.first);
      rc = 1;
    }
  }
  std::fprintf(stderr, "# logged %" PRIu64 " frames, sent %" PRIu64 " -> %s\n",
               recorder.frames(), sent,
               sent == recorder.frames() && !rc ? "OK" : "MISMATCH");
  if (sent != recorder.frames()) rc = 1;

  std::fclose(out);
  // Exit without running the destructors of the devices, channels and timers
  // that still have operations pending on the (stopped) loop.
  std::fflush(stderr);
  std::_Exit(rc);
}
