--[[
   lj9da.lua: the autopilot supervises the lj9da-bridge (Futaba LJ9DA41 linear servos on RS485).

   Copy it into the autopilot's scripts/ folder (APM/scripts on an SD card; scripts/ in a SITL's
   working folder), set SCR_ENABLE 1 and reboot. ArduPilot 4.5 or newer (mavlink:receive_chan,
   arming auxiliary authorisation, param:add_table).

   What it listens to, on any MAVLink link (the bridge's messages reach the script as the
   autopilot receives them):
   - the bridge's HEARTBEAT (system LJ9_SYSID, component LJ9_COMPID), 1 Hz;
   - one NAMED_VALUE_INT per servo of the bridge's mapping, named "LJ9_" + the servo's label
     (LJ9_rudder, LJ9_ail_l, ...), 1 Hz and at once on a change. Its value is a bit field,
     0 = all well: 1 offline, 2 starting, 4 over temperature, 8 stalled, 16 failsafe (the bridge
     holds its failsafe positions: the autopilot's outputs stopped reaching it), 32 stale.

   What it does:
   - Refuses arming (auxiliary authorisation failed) while the bridge or a servo is not well,
     with the reason: "LJ9DA: rudder offline", "LJ9DA: ail_l over temperature",
     "LJ9DA: elev stalled", "LJ9DA: rudder in failsafe", "LJ9DA: rudder silent 3 s" (its state
     not heard for LJ9_TIMEOUT while the bridge's HEARTBEAT still comes), "LJ9DA: bridge silent
     3 s" (its HEARTBEAT not heard for LJ9_TIMEOUT, or never). Any nonzero state refuses
     arming. ArduPlane shows it as "PreArm: LJ9DA: ..." (and "Arm: ..." on an arm command).
   - Armed, when the bridge goes silent or a servo is lost (offline, or its state silent), says
     so once at CRITICAL ("LJ9DA: bridge silent 3 s", "LJ9DA: rudder offline") and, if
     LJ9_FS_MODE >= 0, switches to that mode (once per loss); says once at INFO when it is back
     ("LJ9DA: bridge back", "LJ9DA: rudder back"). Other faults in flight (temperature, stall)
     are left to the bridge's own STATUSTEXTs.
   - Writes every servo state it hears into the autopilot's log (the .bin of the SD card) as
     message LJ9S: Label (the servo's label), State (the bits above), about once a second per
     servo and at each change. Mission Planner, UAV Log Viewer and mavlogdump.py show it.
   - Runs every 100 ms. On a vehicle without the bridge it refuses arming with "bridge silent"
     and does nothing else.

   Parameters (parameter table key 147, prefix LJ9_):
   LJ9_ENABLE   1    0: the script does nothing and does not hold arming back.
   LJ9_COMPID   140  The bridge's MAVLink component id (its mapping's component_id).
   LJ9_SYSID    0    The bridge's MAVLink system id; 0: the autopilot's own (MAV_SYSID or
                     SYSID_THISMAV).
   LJ9_TIMEOUT  3    Seconds without the bridge's HEARTBEAT, or without a servo's state, that
                     mean it is lost (at least 1.5: both come at 1 Hz).
   LJ9_FS_MODE  -1   The flight mode number to switch to, armed, when the bridge goes silent or
                     a servo is lost; -1: say it, no mode change. Mode numbers (the vehicle's
                     Mode::Number in ArduPlane/mode.h, ArduCopter/mode.h, Rover/mode.h):
                     Plane: RTL 11, QLAND 20, QRTL 21; Copter: RTL 6, LAND 9;
                     Rover: HOLD 4, RTL 11.
--]]

local PARAM_TABLE_KEY = 147
local PARAM_TABLE_PREFIX = "LJ9_"
local UPDATE_MS = 100
local MAV_SEVERITY = { EMERGENCY = 0, ALERT = 1, CRITICAL = 2, ERROR = 3, WARNING = 4, NOTICE = 5, INFO = 6, DEBUG = 7 }
local HEARTBEAT_ID = 0
local NAMED_VALUE_INT_ID = 252
-- The bridge sends each servo's state with its HEARTBEAT at 1 Hz: a HEARTBEAT this much newer
-- than a servo's last state means that state is missing, not that the whole bridge just stopped.
local STATE_PERIOD_MS = 1500

assert(param:add_table(PARAM_TABLE_KEY, PARAM_TABLE_PREFIX, 5), "LJ9DA: could not add the LJ9_ parameters")

local function bind_add_param(name, idx, default_value)
   assert(param:add_param(PARAM_TABLE_KEY, idx, name, default_value), "LJ9DA: could not add LJ9_" .. name)
   return Parameter(PARAM_TABLE_PREFIX .. name)
end

local LJ9_ENABLE = bind_add_param("ENABLE", 1, 1)
local LJ9_COMPID = bind_add_param("COMPID", 2, 140)
local LJ9_SYSID = bind_add_param("SYSID", 3, 0)
local LJ9_TIMEOUT = bind_add_param("TIMEOUT", 4, 3)
local LJ9_FS_MODE = bind_add_param("FS_MODE", 5, -1)

-- queue depth, number of message ids
mavlink:init(25, 2)
mavlink:register_rx_msgid(HEARTBEAT_ID)
mavlink:register_rx_msgid(NAMED_VALUE_INT_ID)

local auth_id = arming:get_aux_auth_id()

-- times are millis() as plain integers (wrapping after 49 days of uptime is not handled)
local bridge_heard = nil -- the bridge's last HEARTBEAT, nil: never
local bridge_since = nil -- the first HEARTBEAT of its current run (no silence since)
local servos = {}        -- label -> { value = bits, heard = ms }
local labels = {}        -- the labels heard, sorted
local lost = {}          -- armed: what is lost and was said ("bridge", or a label) -> true
local mode_pending = false
local mode_refused_said = false
local last_mode_try = nil

local BITS = {
   { 1, "offline" },
   { 2, "starting" },
   { 4, "over temperature" },
   { 8, "stalled" },
   { 16, "in failsafe" },
   { 32, "stale" },
}
local KNOWN_BITS = 63
local OFFLINE_BIT = 1

local function own_sysid()
   return param:get("MAV_SYSID") or param:get("SYSID_THISMAV") or 1
end

local function timeout_ms()
   return math.max(LJ9_TIMEOUT:get(), 1.5) * 1000
end

local function silent_text()
   return string.format("silent %g s", timeout_ms() / 1000)
end

local function describe(value)
   local parts = {}
   for _, b in ipairs(BITS) do
      if value & b[1] ~= 0 then
         parts[#parts + 1] = b[2]
      end
   end
   if value & ~KNOWN_BITS ~= 0 then
      parts[#parts + 1] = string.format("state 0x%x", value)
   end
   return table.concat(parts, ", ")
end

-- A received mavlink_message_t, as receive_chan gives it: its sender, message id and payload,
-- zero-filled to `n` bytes (MAVLink 2 trims trailing zeros). Two layouts: 291 bytes (1-byte
-- sysid, payload from byte 13: checksum u16, magic, len, incompat, compat, seq, sysid, compid,
-- msgid u24) and, with MAVLink 2.1's 32-bit sysid, 299 bytes (sysid u32, payload from byte 16).
local function decode(msg, n)
   local len = string.unpack("<B", msg, 4)
   local sysid, compid, msgid, ofs
   if #msg >= 299 then
      sysid, compid, msgid = string.unpack("<I4BI3", msg, 8)
      ofs = 16
   else
      sysid, compid, msgid = string.unpack("<BBI3", msg, 8)
      ofs = 13
   end
   local payload = string.sub(msg, ofs, ofs + math.min(len, n) - 1)
   if #payload < n then
      payload = payload .. string.rep("\0", n - #payload)
   end
   return sysid, compid, msgid, payload
end

local function read_messages()
   local sysid = LJ9_SYSID:get()
   if sysid == 0 then
      sysid = own_sysid()
   end
   local compid = LJ9_COMPID:get()
   local limit = timeout_ms()
   for _ = 1, 25 do
      local msg, _, timestamp = mavlink:receive_chan()
      if not msg then
         return
      end
      local from_sys, from_comp, msgid, payload = decode(msg, 18)
      if from_sys == sysid and from_comp == compid then
         local at = timestamp:toint()
         if msgid == HEARTBEAT_ID then
            if bridge_heard == nil or at - bridge_heard > limit then
               bridge_since = at
            end
            bridge_heard = at
         elseif msgid == NAMED_VALUE_INT_ID then
            -- NAMED_VALUE_INT: time_boot_ms u32, value i32, name char[10]
            local value, name = string.unpack("<i4c10", payload, 5)
            local nul = string.find(name, "\0", 1, true)
            if nul then
               name = string.sub(name, 1, nul - 1)
            end
            if string.sub(name, 1, 4) == "LJ9_" and #name > 4 then
               local label = string.sub(name, 5)
               local s = servos[label]
               if not s then
                  s = {}
                  servos[label] = s
                  labels[#labels + 1] = label
                  table.sort(labels)
               end
               s.value = value
               s.heard = at
               -- into the autopilot's own log (.bin): LJ9S, one row per state heard
               logger:write("LJ9S", "Label,State", "Ni", "--", "--", label, value)
            end
         end
      end
   end
end

-- What is wrong now, as { key, text, lost } in order: the bridge first, then the servos by
-- label. `lost`: a loss that acts in flight (silence, offline).
local function problems(now)
   local limit = timeout_ms()
   if bridge_heard == nil or now - bridge_heard > limit then
      return { { "bridge", "bridge " .. silent_text(), true } }
   end
   local list = {}
   for _, label in ipairs(labels) do
      local s = servos[label]
      -- silent: not heard for the timeout while the bridge's HEARTBEAT kept coming (a servo's
      -- state comes with each HEARTBEAT; a bridge that just stopped or just came back is not
      -- its servos' silence)
      local from = math.max(s.heard, bridge_since)
      if now - from > limit and bridge_heard - from > STATE_PERIOD_MS then
         list[#list + 1] = { label, label .. " " .. silent_text(), true }
      elseif s.value ~= 0 then
         list[#list + 1] = { label, label .. " " .. describe(s.value), s.value & OFFLINE_BIT ~= 0 }
      end
   end
   if #labels == 0 then
      -- a bridge whose servo states have not come (yet, or an older bridge, or servo_state off)
      list[1] = { "states", "no servo state heard", false }
   end
   return list
end

local function update_arming(list)
   if auth_id == nil then
      auth_id = arming:get_aux_auth_id()
      if auth_id == nil then
         return
      end
   end
   if #list == 0 then
      arming:set_aux_auth_passed(auth_id)
      return
   end
   local text = "LJ9DA: " .. list[1][2]
   if #list > 1 then
      text = text .. string.format(" (+%d more)", #list - 1)
   end
   arming:set_aux_auth_failed(auth_id, text)
end

local function try_mode(now)
   local mode = math.floor(LJ9_FS_MODE:get())
   if mode < 0 then
      mode_pending = false
      return
   end
   if last_mode_try ~= nil and now - last_mode_try < 1000 then
      return
   end
   last_mode_try = now
   if vehicle:set_mode(mode) then
      mode_pending = false
      gcs:send_text(MAV_SEVERITY.INFO, string.format("LJ9DA: mode %d", mode))
   elseif not mode_refused_said then
      mode_refused_said = true
      gcs:send_text(MAV_SEVERITY.WARNING, string.format("LJ9DA: mode %d refused, trying again", mode))
   end
end

local function update_flight(now, list)
   if not arming:is_armed() then
      lost = {}
      mode_pending = false
      return
   end
   local now_lost = {}
   local new_loss = false
   for _, p in ipairs(list) do
      if p[3] then
         now_lost[p[1]] = true
         if not lost[p[1]] then
            gcs:send_text(MAV_SEVERITY.CRITICAL, "LJ9DA: " .. p[2])
            new_loss = true
         end
      end
   end
   for key, _ in pairs(lost) do
      if not now_lost[key] then
         if now_lost.bridge then
            now_lost[key] = true -- not heard while the bridge is silent: not back
         else
            gcs:send_text(MAV_SEVERITY.INFO, "LJ9DA: " .. key .. " back")
         end
      end
   end
   if new_loss and next(lost) == nil then
      -- the first loss of this episode: act once
      mode_pending = true
      mode_refused_said = false
      last_mode_try = nil
   end
   lost = now_lost
   if mode_pending then
      try_mode(now)
   end
end

local enabled = true

local function update()
   if LJ9_ENABLE:get() < 1 then
      if enabled and auth_id ~= nil then
         arming:set_aux_auth_passed(auth_id)
      end
      enabled = false
      return
   end
   enabled = true
   read_messages()
   local now = millis():toint()
   local list = problems(now)
   update_arming(list)
   update_flight(now, list)
end

local function protected_wrapper()
   local ok, err = pcall(update)
   if not ok then
      gcs:send_text(MAV_SEVERITY.ERROR, "LJ9DA: internal error: " .. tostring(err))
      if auth_id ~= nil then
         arming:set_aux_auth_failed(auth_id, "LJ9DA: script error")
      end
      return protected_wrapper, 1000
   end
   return protected_wrapper, UPDATE_MS
end

if auth_id == nil then
   gcs:send_text(MAV_SEVERITY.WARNING, "LJ9DA: no auxiliary arming id free")
end
gcs:send_text(MAV_SEVERITY.INFO, "LJ9DA: supervising the bridge")

return protected_wrapper()
