//! Word error rate: the word-level edit distance between what was said and what was
//! heard, over the words said. Both sides are normalised as for English speech
//! recognition: lower-cased, punctuation dropped, number words as digits, British
//! spellings as American ("Move the turtle two metres." = "move the turtle 2 meters").

/// Number words written as digits, and spellings made one.
const SAME: &[(&str, &str)] = &[
    ("zero", "0"),
    ("one", "1"),
    ("two", "2"),
    ("three", "3"),
    ("four", "4"),
    ("five", "5"),
    ("six", "6"),
    ("seven", "7"),
    ("eight", "8"),
    ("nine", "9"),
    ("ten", "10"),
    ("eleven", "11"),
    ("twelve", "12"),
    ("fifteen", "15"),
    ("twenty", "20"),
    ("thirty", "30"),
    ("forty", "40"),
    ("fifty", "50"),
    ("sixty", "60"),
    ("ninety", "90"),
    ("hundred", "100"),
    ("metre", "meter"),
    ("metres", "meters"),
    ("centimetres", "centimeters"),
    ("colour", "color"),
    ("okay", "ok"),
];

/// The words of `text` as compared.
pub fn words(text: &str) -> Vec<String> {
    text.split(|c: char| c.is_whitespace() || c == '-' || c == '/')
        .map(|w| {
            let w = w
                .chars()
                .filter(|c| c.is_alphanumeric() || *c == '.' || *c == '\'')
                .collect::<String>()
                .trim_matches(['.', '\''])
                .to_lowercase();
            SAME.iter()
                .find(|(from, _)| *from == w)
                .map_or(w, |(_, to)| to.to_string())
        })
        .filter(|w| !w.is_empty())
        .collect()
}

/// Substitutions, deletions and insertions turning `said` into `heard`, and the number
/// of words said.
pub fn errors(said: &str, heard: &str) -> (usize, usize) {
    let (a, b) = (words(said), words(heard));
    let mut prev: Vec<usize> = (0..=b.len()).collect();
    for (i, x) in a.iter().enumerate() {
        let mut row = vec![i + 1; b.len() + 1];
        for (j, y) in b.iter().enumerate() {
            row[j + 1] = (prev[j] + usize::from(x != y))
                .min(prev[j + 1] + 1)
                .min(row[j] + 1);
        }
        prev = row;
    }
    (prev[b.len()], a.len())
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn counts_edits_over_the_words_said() {
        assert_eq!(
            errors("Move the turtle, please.", "move the turtle please"),
            (0, 4)
        );
        assert_eq!(
            errors("show the ROS topics", "show the rose topics"),
            (1, 4)
        );
        assert_eq!(errors("show the ROS topics", "show ROS topics now"), (2, 4));
        assert_eq!(errors("turn 90 degrees", ""), (3, 3));
        assert_eq!(
            words("/turtle1/pose at 2.5 m."),
            ["turtle1", "pose", "at", "2.5", "m"]
        );
        assert_eq!(
            errors("Move forward two metres.", "move forward 2 meters"),
            (0, 4)
        );
    }
}
