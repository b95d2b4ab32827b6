//! Optional needs switched off and on while the module runs (adjustable autonomy).

use super::{manager, module, ms, sim};
use crate::contract::{AgentConfig, ContractAgent, ModuleId, NeedSpec, ServiceOffer};

const MANAGER: ModuleId = ModuleId(0);
const CLIENT: ModuleId = ModuleId(1);
const WALL: ModuleId = ModuleId(2);

fn client() -> ContractAgent {
    let cfg = AgentConfig::new(CLIENT)
        .provide(ServiceOffer::new("Human control", ""))
        .need(NeedSpec::required("Robot control", 1))
        .need(NeedSpec::optional("Follow wall", 2, 0.3));
    let mut a = ContractAgent::new(cfg).unwrap();
    a.set_quality(1.0);
    a
}

#[test]
fn a_switched_off_need_ends_its_contract_and_is_not_called_nor_penalised() {
    let mut s = sim();
    s.add(manager(MANAGER.0, &["Human control"]));
    s.add(client());
    s.add(module(3, 1.0, &["Robot control"], &[]));
    s.add(module(WALL.0, 0.9, &["Follow wall"], &[]));
    s.run_for(ms(1000));
    assert_eq!(s.provider_of(CLIENT, 2), Some(WALL));
    assert!(s.agent(WALL).unwrap().is_active());

    // Off: the provider is released (it goes inactive) and stays released.
    s.with(CLIENT, |a, _| {
        assert!(a.set_need_enabled(2, false));
        Vec::new()
    });
    s.run_for(ms(100));
    assert_eq!(s.provider_of(CLIENT, 2), None);
    assert!(!s.agent(WALL).unwrap().is_active());
    s.run_for(ms(2000));
    assert_eq!(s.provider_of(CLIENT, 2), None);
    assert!(!s.agent(CLIENT).unwrap().need_enabled(2));

    // No provider at all while off: no penalty on the client's value.
    s.kill(WALL, true);
    s.run_for(ms(1500));
    let v = s.agent(CLIENT).unwrap().value(s.now()).unwrap();
    assert!((v - 1.0).abs() < 1e-9, "{v}");

    // On again with no provider: unmet, penalised; a provider appears: contracted.
    s.with(CLIENT, |a, _| {
        assert!(a.set_need_enabled(2, true));
        Vec::new()
    });
    s.run_for(ms(200));
    let v = s.agent(CLIENT).unwrap().value(s.now()).unwrap();
    assert!((v - 0.7).abs() < 1e-9, "{v}");
    s.add(module(4, 0.9, &["Follow wall"], &[]));
    s.run_for(ms(1000));
    assert_eq!(s.provider_of(CLIENT, 2), Some(ModuleId(4)));
}

#[test]
fn required_and_unknown_needs_cannot_be_switched_off() {
    let mut a = client();
    assert!(!a.set_need_enabled(1, false));
    assert!(!a.set_need_enabled(9, false));
    assert!(a.need_enabled(1));
}
