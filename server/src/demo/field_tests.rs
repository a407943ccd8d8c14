use super::*;

fn float(bank: &Bank, address: u16) -> f32 {
    let hi = bank.input_registers[&address];
    let lo = bank.input_registers[&(address + 1)];
    f32::from_bits(u32::from(hi) << 16 | u32::from(lo))
}

#[test]
fn the_meter_reads_what_a_meter_on_a_230_v_line_would() {
    let devices = Devices::new();
    for phase in 0..3 {
        let volts = float(&devices.meter, phase * 2);
        assert!((227.0..233.0).contains(&volts), "L{} {volts} V", phase + 1);
        let amps = float(&devices.meter, 6 + phase * 2);
        assert!((0.6..1.0).contains(&amps), "L{} {amps} A", phase + 1);
    }
    assert!((49.9..50.1).contains(&float(&devices.meter, 70)));
    assert_eq!(float(&devices.meter, 72), float(&devices.meter, 342));
}

#[test]
fn an_output_switched_on_is_felt_on_its_input_and_on_the_meter() {
    let mut devices = Devices::new();
    let before = float(&devices.meter, 6);
    let answer = devices.answer(
        IO,
        &Request::WriteSingleCoil {
            address: 0,
            value: true,
        },
    );
    assert_eq!(answer, Ok(Response::Written));
    devices.step();
    assert_eq!(
        devices.answer(
            IO,
            &Request::ReadDiscreteInputs {
                address: 0,
                count: 2
            }
        ),
        Ok(Response::Bits(vec![true, false]))
    );
    let after = float(&devices.meter, 6);
    assert!(after > before + 1.5, "L1 {before} A, then {after} A");
    let energy = float(&devices.meter, 72);
    assert!(energy > 1234.5, "energy counts: {energy}");
}

#[test]
fn an_address_past_the_last_and_a_missing_unit_are_refused_as_a_device_would() {
    let mut devices = Devices::new();
    let past = Request::ReadHoldingRegisters {
        address: 0xFFF0,
        count: 17,
    };
    assert_eq!(
        devices.answer(IO, &past),
        Err(Exception::ILLEGAL_DATA_ADDRESS)
    );
    let read = Request::ReadHoldingRegisters {
        address: 0x8000,
        count: 1,
    };
    assert_eq!(
        devices.answer(IO, &read),
        Ok(Response::Registers(vec![IO_VERSION]))
    );
    assert_eq!(devices.answer(7, &read), Err(Exception(11)));
    let write = Request::WriteMultipleRegisters {
        address: 0xFFFF,
        values: vec![1, 2],
    };
    assert_eq!(
        devices.answer(METER, &write),
        Err(Exception::ILLEGAL_DATA_ADDRESS)
    );
}
