//! The small XML reader under the model file: `quick-xml`'s events built
//! into a tree of elements with their attributes and text, so that the
//! layout can be looked up by name. A document that is not well formed is
//! refused with the line of the problem.

use quick_xml::events::Event;

/// An XML element with its attributes, text and children.
#[derive(Debug, Default)]
pub(super) struct Element {
    /// The tag name.
    pub(super) name: String,
    attributes: Vec<(String, String)>,
    /// The text directly inside, all pieces concatenated.
    pub(super) text: String,
    children: Vec<Element>,
}

impl Element {
    pub(super) fn attribute(&self, key: &str) -> Option<&str> {
        self.attributes
            .iter()
            .find(|(k, _)| k == key)
            .map(|(_, v)| v.as_str())
    }

    pub(super) fn child(&self, name: &str) -> Option<&Element> {
        self.children.iter().find(|c| c.name == name)
    }

    pub(super) fn children_named<'a>(&'a self, name: &'a str) -> impl Iterator<Item = &'a Element> {
        self.children.iter().filter(move |c| c.name == name)
    }

    /// Sets attribute `key` to `value`, added if it is not there.
    pub(super) fn set_attribute(&mut self, key: &str, value: &str) {
        match self.attributes.iter_mut().find(|(k, _)| k == key) {
            Some((_, v)) => *v = value.to_owned(),
            None => self.attributes.push((key.to_owned(), value.to_owned())),
        }
    }

    /// Calls `visit` on this element and every element under it, depth
    /// first, until one fails.
    pub(super) fn visit_mut(
        &mut self,
        visit: &mut dyn FnMut(&mut Element) -> Result<(), String>,
    ) -> Result<(), String> {
        visit(self)?;
        self.children
            .iter_mut()
            .try_for_each(|c| c.visit_mut(visit))
    }

    /// The child `DataArray` whose `Name` is `name`.
    pub(super) fn data_array(&self, name: &str) -> Option<&Element> {
        self.children_named("DataArray")
            .find(|a| a.attribute("Name") == Some(name))
    }
}

/// 1-based line of byte offset `pos` in `text`.
fn line_of(text: &str, pos: u64) -> usize {
    let end = usize::try_from(pos).unwrap_or(usize::MAX).min(text.len());
    text.as_bytes()[..end]
        .iter()
        .filter(|&&b| b == b'\n')
        .count()
        + 1
}

/// The element tree of `text`: one root element, or what is wrong and
/// where (the line).
pub(super) fn parse_xml(text: &str) -> Result<Element, String> {
    let mut reader = quick_xml::Reader::from_str(text);
    reader.config_mut().expand_empty_elements = true;
    let mut stack: Vec<Element> = Vec::new();
    let mut root: Option<Element> = None;
    loop {
        let event = reader.read_event().map_err(|e| {
            format!(
                "malformed XML at line {}: {e}",
                line_of(text, reader.error_position())
            )
        })?;
        match event {
            Event::Start(start) => {
                let mut element = Element {
                    name: String::from_utf8_lossy(start.name().as_ref()).into_owned(),
                    ..Element::default()
                };
                for attribute in start.attributes() {
                    let attribute = attribute.map_err(|e| {
                        format!(
                            "malformed XML attribute at line {}: {e}",
                            line_of(text, reader.buffer_position())
                        )
                    })?;
                    let value = attribute.unescape_value().map_err(|e| {
                        format!(
                            "malformed XML attribute at line {}: {e}",
                            line_of(text, reader.buffer_position())
                        )
                    })?;
                    element.attributes.push((
                        String::from_utf8_lossy(attribute.key.as_ref()).into_owned(),
                        value.into_owned(),
                    ));
                }
                if root.is_some() && stack.is_empty() {
                    return Err(format!(
                        "malformed XML at line {}: a second root element <{}>",
                        line_of(text, reader.buffer_position()),
                        element.name
                    ));
                }
                stack.push(element);
            }
            Event::End(_) => {
                // quick-xml checks that the end tag matches its start tag.
                let Some(element) = stack.pop() else {
                    return Err("malformed XML: an end tag without a start tag".into());
                };
                match stack.last_mut() {
                    Some(parent) => parent.children.push(element),
                    None => root = Some(element),
                }
            }
            Event::Text(t) => {
                let content = t.unescape().map_err(|e| {
                    format!(
                        "malformed XML text at line {}: {e}",
                        line_of(text, reader.buffer_position())
                    )
                })?;
                match stack.last_mut() {
                    Some(element) => element.text.push_str(&content),
                    None if content.trim().is_empty() => {}
                    None => {
                        return Err(format!(
                            "malformed XML at line {}: text outside the root element",
                            line_of(text, reader.buffer_position())
                        ));
                    }
                }
            }
            Event::CData(data) => {
                if let Some(element) = stack.last_mut() {
                    element.text.push_str(&String::from_utf8_lossy(&data));
                }
            }
            Event::Eof => break,
            Event::Empty(_)
            | Event::Comment(_)
            | Event::Decl(_)
            | Event::PI(_)
            | Event::DocType(_) => {}
        }
    }
    if let Some(open) = stack.last() {
        return Err(format!(
            "the file is truncated: element <{}> is never closed",
            open.name
        ));
    }
    root.ok_or_else(|| "no XML element found".to_string())
}

#[cfg(test)]
mod tests {
    #![allow(clippy::unwrap_used, reason = "tests fail loudly on purpose")]

    use super::*;

    #[test]
    fn elements_keep_their_attributes_text_and_children() {
        let root = parse_xml(
            "<?xml version=\"1.0\"?>\n<!-- note -->\n\
             <a k=\"1 &amp; 2\"><b/>x<b>y</b><![CDATA[<z>]]></a>\n",
        )
        .unwrap();
        assert_eq!(root.name, "a");
        assert_eq!(root.attribute("k"), Some("1 & 2"));
        assert_eq!(root.attribute("missing"), None);
        assert_eq!(root.text, "x<z>");
        assert_eq!(root.children_named("b").count(), 2);
        assert_eq!(root.child("b").unwrap().text, "");
    }

    #[test]
    fn data_array_is_found_by_its_name() {
        let root = parse_xml(
            r#"<p><DataArray Name="radius">1</DataArray><DataArray Name="surface">0</DataArray></p>"#,
        )
        .unwrap();
        assert_eq!(root.data_array("surface").unwrap().text, "0");
        assert!(root.data_array("triangle").is_none());
    }

    #[test]
    fn malformed_documents_are_refused_naming_the_problem() {
        for (text, needle) in [
            ("<a>\n<b>\n", "element <b> is never closed"),
            (
                "<a/>\n<b/>",
                "malformed XML at line 2: a second root element <b>",
            ),
            ("<a/>\ntext", "text outside the root element"),
            ("<a>\n</c>", "malformed XML"),
            (" \n ", "no XML element found"),
        ] {
            let err = parse_xml(text).unwrap_err();
            assert!(err.contains(needle), "{text:?}: {err}");
        }
    }
}
