//! The sections front-ends read themselves (`mqtt:`, `opcua:`, and any front-end added
//! later). The config reader knows none of them: it keeps every top-level key it does not
//! read as written ([`Sections::written`]); the front-ends' list reads each into what it
//! makes of it ([`Sections::set`]), which the front-end takes back by key and type.

use std::any::Any;
use std::fmt;
use std::net::SocketAddr;

use crate::yaml::{Node, Report};

/// What a front-end made of its section.
pub(crate) trait Section: SectionObject + fmt::Debug + Send + Sync {
    /// The line of its key, for problems found after reading.
    fn line(&self) -> u64;

    /// Adds the problems of serving this section as configured beyond loopback
    /// (`security:` and `listen:` rules, as for HTTP and gRPC).
    fn check_exposure(&self, _exposure: &Exposure, _report: &mut Report) {}

    /// The address it listens on, when it has one a command line may move (`serve --opcua`).
    fn listen_mut(&mut self) -> Option<&mut SocketAddr> {
        None
    }

    /// Reads what it names outside the config file (a map file), from `base`, so that a
    /// change there is a change of the section; the files it read, whose contents a
    /// reload's hash takes in.
    fn resolve(&mut self, _base: &std::path::Path) {}

    /// The files outside the config file it reads, as resolved.
    fn files(&self) -> Vec<std::path::PathBuf> {
        Vec::new()
    }
}

/// What the section rules of [`Section::check_exposure`] depend on.
#[derive(Debug, Clone, Copy)]
pub(crate) struct Exposure {
    /// No token is configured: whoever reaches a listener is not asked who they are.
    pub(crate) no_tokens: bool,
    /// `security.insecure: true`: the operator accepted serving beyond loopback as is.
    pub(crate) insecure: bool,
}

/// What every [`Section`] is as an object: compared, copied and taken back as its type.
/// Implemented for every `Section` that is `Clone + PartialEq`.
pub(crate) trait SectionObject {
    fn as_any(&self) -> &dyn Any;
    fn as_any_mut(&mut self) -> &mut dyn Any;
    fn boxed(&self) -> Box<dyn Section>;
    fn same(&self, other: &dyn Section) -> bool;
}

impl<T: Section + Clone + PartialEq + 'static> SectionObject for T {
    fn as_any(&self) -> &dyn Any {
        self
    }

    fn as_any_mut(&mut self) -> &mut dyn Any {
        self
    }

    fn boxed(&self) -> Box<dyn Section> {
        Box::new(self.clone())
    }

    fn same(&self, other: &dyn Section) -> bool {
        other.as_any().downcast_ref::<T>() == Some(self)
    }
}

/// One top-level key nobody in the config reader reads.
#[derive(Debug)]
struct Entry {
    key: String,
    /// The line of the key.
    line: u64,
    /// Its value as written (`null` when the key has none).
    node: Node,
    /// What its front-end made of it, once read.
    read: Option<Box<dyn Section>>,
}

impl Clone for Entry {
    fn clone(&self) -> Self {
        Entry {
            key: self.key.clone(),
            line: self.line,
            node: self.node.clone(),
            read: self.read.as_ref().map(|s| s.boxed()),
        }
    }
}

impl PartialEq for Entry {
    fn eq(&self, other: &Self) -> bool {
        self.key == other.key
            && match (&self.read, &other.read) {
                (Some(a), Some(b)) => a.same(b.as_ref()),
                (None, None) => self.node == other.node,
                _ => false,
            }
    }
}

/// The front-ends' sections of one config, in the order written.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct Sections(Vec<Entry>);

impl Sections {
    /// Keeps a top-level key for the front-ends to read.
    pub(crate) fn keep(&mut self, key: &str, line: u64, node: &Node) {
        self.0.push(Entry {
            key: key.to_owned(),
            line,
            node: node.clone(),
            read: None,
        });
    }

    /// Every key kept, with the line of the key and its value as written.
    pub(crate) fn written(&self) -> impl Iterator<Item = (&str, u64, &Node)> {
        self.0.iter().map(|e| (e.key.as_str(), e.line, &e.node))
    }

    /// Keeps what a front-end made of the section `key`; a key not written is added.
    pub(crate) fn set(&mut self, key: &str, section: Box<dyn Section>) {
        match self.0.iter_mut().find(|e| e.key == key) {
            Some(entry) => entry.read = Some(section),
            None => self.0.push(Entry {
                key: key.to_owned(),
                line: section.line(),
                node: Node::null(section.line()),
                read: Some(section),
            }),
        }
    }

    /// What the front-end made of its section `key`, as its type `T`.
    pub fn get<T: 'static>(&self, key: &str) -> Option<&T> {
        let entry = self.0.iter().find(|e| e.key == key)?;
        entry.read.as_ref()?.as_any().downcast_ref()
    }

    /// As [`Sections::get`], to change it (tests, the command line).
    pub fn get_mut<T: 'static>(&mut self, key: &str) -> Option<&mut T> {
        let entry = self.0.iter_mut().find(|e| e.key == key)?;
        entry.read.as_mut()?.as_any_mut().downcast_mut()
    }

    /// The section `key` as read, whatever its type.
    pub(crate) fn section(&self, key: &str) -> Option<&dyn Section> {
        let entry = self.0.iter().find(|e| e.key == key)?;
        entry.read.as_deref()
    }

    /// Has every section read what it names outside the config file, from `base`.
    pub(crate) fn resolve(&mut self, base: &std::path::Path) {
        for entry in &mut self.0 {
            if let Some(section) = entry.read.as_mut() {
                section.resolve(base);
            }
        }
    }

    /// The files outside the config file the sections read.
    pub(crate) fn files(&self) -> Vec<std::path::PathBuf> {
        self.read().flat_map(|s| s.files()).collect()
    }

    /// Every section read.
    pub(crate) fn read(&self) -> impl Iterator<Item = &dyn Section> {
        self.0.iter().filter_map(|e| e.read.as_deref())
    }

    /// The address the section `key` listens on, to move it.
    pub fn listen_mut(&mut self, key: &str) -> Option<&mut SocketAddr> {
        let entry = self.0.iter_mut().find(|e| e.key == key)?;
        entry.read.as_mut()?.listen_mut()
    }
}
