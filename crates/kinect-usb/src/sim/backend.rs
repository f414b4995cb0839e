//! The simulated device's USB surface ([`UsbBackend`]): configuration, interfaces, the command
//! endpoints' OUT/data/completion phases with the protocol's sequence rules and the injected
//! command faults, and the start, events and stop of the streams.

use std::sync::Arc;
use std::time::{Duration, Instant};

use super::{Phase, SIM_FRAME_RATE, SimDevice, SimPacing};
use crate::backend::{EventSink, ResetOutcome, Serviced, StreamHandle, StreamSpec, UsbBackend};
use crate::error::UsbError;
use crate::pool::submit_pool;
use crate::protocol::{self, COLOR_SETTING_ID, COLOR_SETTING_RESPONSE_LEN, SET_MODE_ID, ep};

impl SimDevice {
    fn check(&mut self) -> Result<(), UsbError> {
        if self.gone || self.stale_handle { Err(UsbError::NoDevice) } else { Ok(()) }
    }
}

impl SimDevice {
    fn serviced_since(&self, emitted_before: u64) -> Serviced {
        if self.emitted.get() > emitted_before { Serviced::Delivered } else { Serviced::Idle }
    }
}

impl UsbBackend for SimDevice {
    fn active_config(&mut self) -> Result<u8, UsbError> {
        self.check()?;
        Ok(self.config)
    }

    fn set_config(&mut self, cfg: u8) -> Result<(), UsbError> {
        self.check()?;
        self.transcript.push(format!("set_config {cfg}"));
        self.config = cfg;
        Ok(())
    }

    fn reset(&mut self) -> Result<ResetOutcome, UsbError> {
        self.check()?;
        self.transcript.push("reset".into());
        if self.faults.reset_reenumerates {
            // Once: the device comes back at a new address, this handle is dead.
            self.faults.reset_reenumerates = false;
            self.stale_handle = true;
            return Ok(ResetOutcome::Reenumerated);
        }
        Ok(ResetOutcome::Ok)
    }

    fn reopen(&mut self, wait: Duration) -> Result<(), UsbError> {
        self.transcript.push("close".into());
        std::thread::sleep(wait);
        if self.gone || self.faults.lost_after_reenumeration {
            return Err(UsbError::NoDevice);
        }
        self.transcript.push(format!("reopen serial {}", self.profile.serial));
        // A fresh enumeration: unconfigured, nothing claimed, alt 0.
        self.stale_handle = false;
        self.config = 0;
        self.claimed = [false; 2];
        self.alt1 = 0;
        Ok(())
    }

    fn claim(&mut self, iface: u8) -> Result<(), UsbError> {
        self.check()?;
        if self.faults.busy {
            return Err(UsbError::Busy);
        }
        self.transcript.push(format!("claim {iface}"));
        self.claimed[iface as usize & 1] = true;
        Ok(())
    }

    fn release(&mut self, iface: u8) -> Result<(), UsbError> {
        self.check()?;
        self.transcript.push(format!("release {iface}"));
        self.claimed[iface as usize & 1] = false;
        Ok(())
    }

    fn set_alt(&mut self, iface: u8, alt: u8) -> Result<(), UsbError> {
        self.check()?;
        self.transcript.push(format!("set_alt {iface} {alt}"));
        if iface == 1 {
            self.alt1 = alt;
        }
        Ok(())
    }

    fn control_out(
        &mut self,
        req_type: u8,
        req: u8,
        value: u16,
        index: u16,
        _data: &[u8],
        _t: Duration,
    ) -> Result<usize, UsbError> {
        self.check()?;
        self.transcript.push(format!("control {req_type:02x} {req:02x} {value} {index:#x}"));
        if req_type == 0x01 && req == 0x03 {
            self.suspended = (index >> 8) & 1 == 1;
        }
        Ok(0)
    }

    fn bulk_out(&mut self, ep_: u8, data: &[u8], _t: Duration) -> Result<usize, UsbError> {
        self.check()?;
        if ep_ != ep::COMMAND_OUT {
            return Err(UsbError::NotSupported);
        }
        if self.halted_out {
            return Err(UsbError::Stall);
        }
        if !self.claimed[0] {
            self.violations.push("command before claiming interface 0".into());
        }
        let m = match protocol::parse_command(data) {
            Ok(m) => m,
            Err(e) => {
                self.violations.push(e.to_string());
                self.halted_out = true;
                return Err(UsbError::Stall);
            }
        };
        self.transcript.push(format!("cmd {:#04x} seq {} {:?}", m.id, m.sequence, m.params));
        if self.faults.stall_command == Some(m.id) {
            self.faults.stall_command = None;
            self.halted_out = true;
            return Err(UsbError::Stall);
        }
        let mut completion_status = 0;
        match m.id {
            COLOR_SETTING_ID => {
                // Colour settings always carry sequence 0 and do not advance it (protocol §3.3).
                if m.sequence != 0 {
                    self.violations.push(format!(
                        "colour setting (0x3E) with sequence {}, must be 0",
                        m.sequence
                    ));
                }
                if m.max_response_len != COLOR_SETTING_RESPONSE_LEN as u32 {
                    self.violations.push(format!(
                        "colour setting (0x3E) max_response_len {}, must be 16",
                        m.max_response_len
                    ));
                }
            }
            SET_MODE_ID
                if m.sequence != self.expected_seq
                    && !(self.led_ambiguous && m.sequence == self.expected_seq.wrapping_add(1)) =>
            {
                // Out of the counter: the LED API (sequence 0, protocol §4.9).
                if m.sequence != 0 {
                    self.violations.push(format!(
                        "command 0x4b: sequence {} expected {} (or 0 for the LED API)",
                        m.sequence, self.expected_seq
                    ));
                }
                completion_status = self.apply_led(&m.params, true);
            }
            _ => {
                let ok = m.sequence == self.expected_seq
                    || (self.led_ambiguous && m.sequence == self.expected_seq.wrapping_add(1));
                if !ok {
                    self.violations.push(format!(
                        "command {:#x}: sequence {} expected {}",
                        m.id, m.sequence, self.expected_seq
                    ));
                }
                // A 0x4B at sequence 0 when the counter is also at 0: LED API or first command?
                let ambiguous = m.id == SET_MODE_ID && m.sequence == 0 && self.expected_seq == 0;
                if ambiguous {
                    self.led_ambiguous = true;
                    completion_status = self.apply_led(&m.params, true);
                } else {
                    self.led_ambiguous = false;
                    self.expected_seq = m.sequence.wrapping_add(1);
                    if m.id == SET_MODE_ID {
                        self.apply_led(&m.params, false);
                    }
                }
            }
        }
        if m.id == 0x09 && !self.status_ready_seen && !self.faults.status_never_ready {
            self.violations.push("InitStreams before the status poll reported ready".into());
        }
        if m.id == 0x2B {
            self.streaming_on = m.params.first() == Some(&1);
        }
        let resp = self.respond(&m);
        let phase = if m.max_response_len > 0 { Phase::Data } else { Phase::Completion };
        self.pending = Some((m, resp, phase, completion_status));
        Ok(data.len())
    }

    fn bulk_in(&mut self, ep_: u8, buf: &mut [u8], _t: Duration) -> Result<usize, UsbError> {
        self.check()?;
        if ep_ != ep::COMMAND_IN {
            return Err(UsbError::NotSupported);
        }
        let Some((m, mut resp, phase, cstatus)) = self.pending.take() else {
            return Err(UsbError::Timeout);
        };
        if self.faults.timeout_command == Some(m.id) {
            self.faults.timeout_command = None;
            return Err(UsbError::Timeout);
        }
        let seq = if self.faults.wrong_completion_sequence {
            m.sequence.wrapping_add(7)
        } else {
            m.sequence
        };
        match phase {
            Phase::Data if self.faults.premature_completion == Some(m.id) => {
                self.faults.premature_completion = None;
                let c = protocol::encode_completion(seq);
                let n = c.len().min(buf.len());
                buf[..n].copy_from_slice(&c[..n]);
                Ok(n)
            }
            Phase::Data => {
                if self.faults.short_response == Some(m.id) {
                    self.faults.short_response = None;
                    resp.truncate(resp.len() / 2);
                }
                if buf.len() > m.max_response_len as usize {
                    self.violations.push(format!(
                        "read of {} bytes exceeds max_response_len {}",
                        buf.len(),
                        m.max_response_len
                    ));
                }
                let n = resp.len().min(buf.len());
                buf[..n].copy_from_slice(&resp[..n]);
                self.pending = Some((m, Vec::new(), Phase::Completion, cstatus));
                Ok(n)
            }
            Phase::Completion => {
                let c = protocol::encode_completion_with_status(seq, cstatus);
                let n = c.len().min(buf.len());
                buf[..n].copy_from_slice(&c[..n]);
                Ok(n)
            }
        }
    }

    fn clear_halt(&mut self, ep_: u8) -> Result<(), UsbError> {
        self.check()?;
        self.transcript.push(format!("clear_halt {ep_:#04x}"));
        if ep_ == ep::COMMAND_OUT {
            self.halted_out = false;
        }
        self.pending = None;
        Ok(())
    }

    fn iso_bytes_per_interval(&mut self, _ep: u8, _alt: u8) -> Result<u32, UsbError> {
        self.check()?;
        Ok(self.profile.bytes_per_interval)
    }

    fn start_stream(
        &mut self,
        spec: StreamSpec,
        sink: Arc<dyn EventSink>,
    ) -> Result<StreamHandle, UsbError> {
        self.check()?;
        if self.paced_since.is_none() {
            self.paced_since = Some((Instant::now(), 0));
        }
        let h = StreamHandle(self.next_handle);
        self.next_handle += 1;
        match spec {
            StreamSpec::Iso { packet_size, transfers, .. } => {
                if self.alt1 != 1 || !self.streaming_on || self.suspended {
                    self.violations.push("iso stream started before alt 1 + streaming on".into());
                }
                self.transcript.push("start_stream iso".into());
                // The pool's submissions, through the same policy as the libusb pool.
                let fail = self.faults.depth_submit_failures;
                let first_failing = transfers.saturating_sub(fail.map_or(0, |f| f.0));
                let submitted = submit_pool(transfers, |i| match fail {
                    Some((_, e)) if i >= first_failing => Err(e),
                    _ => Ok(()),
                })?;
                self.iso_in_flight = submitted.in_flight;
                for ev in submitted.retired_events() {
                    sink.deliver(ev);
                }
                self.iso_sink = Some(sink);
                // Build the forward-modelled frames now, not inside a frame wait.
                self.raw_frames();
                self.iso = Some((h, packet_size));
            }
            StreamSpec::Bulk { size, .. } => {
                self.transcript.push("start_stream bulk".into());
                self.bulk = Some((h, size));
                self.bulk_sink = Some(sink);
            }
        }
        Ok(h)
    }

    fn service(&mut self, timeout: Duration) -> Result<Serviced, UsbError> {
        self.check()?;
        if self.iso.is_none() && self.bulk.is_none() {
            return Ok(Serviced::Idle);
        }
        let before = self.emitted.get();
        if self.replay.is_some() {
            self.replay_next();
            return Ok(self.serviced_since(before));
        }
        match self.pacing {
            SimPacing::Lockstep => {
                self.generate_frame_period();
                Ok(self.serviced_since(before))
            }
            SimPacing::RealTime => {
                let (t0, done) = self.paced_since.unwrap_or((Instant::now(), 0));
                let period = Duration::from_secs(1) / SIM_FRAME_RATE;
                // Period k is due at t0 + k × period (the first at the start).
                let due_at = |k: u64| t0 + period * k as u32;
                let now = Instant::now();
                if due_at(done) > now {
                    let wait = due_at(done) - now;
                    if wait > timeout {
                        std::thread::sleep(timeout);
                        return Ok(Serviced::Idle);
                    }
                    std::thread::sleep(wait);
                }
                let elapsed = Instant::now().saturating_duration_since(t0);
                let due = (elapsed.as_nanos() / period.as_nanos()) as u64 + 1;
                for _ in done..due {
                    self.generate_frame_period();
                }
                self.paced_since = Some((t0, due.max(done)));
                Ok(self.serviced_since(before))
            }
        }
    }

    fn stop_stream(&mut self, h: StreamHandle, _max_wait: Duration) -> Result<(), UsbError> {
        self.transcript.push("stop_stream".into());
        if self.iso.map(|s| s.0) == Some(h) {
            self.iso = None;
            self.iso_sink = None;
        }
        if self.bulk.map(|s| s.0) == Some(h) {
            self.bulk = None;
            self.bulk_sink = None;
        }
        if self.iso.is_none() && self.bulk.is_none() {
            self.paced_since = None;
        }
        self.check()
    }
}
